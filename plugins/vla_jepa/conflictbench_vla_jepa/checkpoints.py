"""What a VLA-JEPA checkpoint folder must hold, checked without torch (the client checks before starting a server).

A LeRobot ``vla_jepa`` checkpoint is a folder with ``config.json`` (``"type": "vla_jepa"``), ``model.safetensors``
and the processor pipelines (``policy_preprocessor.json``, ``policy_postprocessor.json`` and their state files:
the normalization statistics), as ``save_pretrained`` writes them. VLA-JEPA's own training runs (starVLA's
``checkpoints/steps_N_pytorch_model.pt`` with ``config.yaml`` and ``dataset_statistics.json``) are not LeRobot
checkpoints: serve those with upstream's ``server_policy.py`` and point ``model.server`` at it.
"""

from __future__ import annotations

import json
from pathlib import Path

from conflictbench_serving import checkpoints as shared
from conflictbench_serving.checkpoints import CheckpointError

__all__ = ["POLICY_TYPE", "CheckpointError", "check_checkpoint", "fingerprint"]

POLICY_TYPE = "vla_jepa"
WEIGHTS_FILE = "model.safetensors"
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")


def check_checkpoint(checkpoint: str | Path) -> Path:
    """The folder, checked to hold a LeRobot VLA-JEPA checkpoint; :class:`CheckpointError` saying why not."""
    folder = Path(checkpoint).expanduser()
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder}")
    config = folder / "config.json"
    try:
        kind = json.loads(config.read_text()).get("type")
    except FileNotFoundError:
        hint = " (a VLA-JEPA training run? serve it with upstream's server_policy.py, then model.server=...)"
        raise CheckpointError(f"{folder} is not a LeRobot checkpoint (no config.json){hint}") from None
    except (OSError, ValueError, AttributeError) as exc:
        raise CheckpointError(f"cannot read {config}: {exc}") from None
    if kind != POLICY_TYPE:
        raise CheckpointError(f"{folder} holds a {kind or 'untyped'} policy, not a {POLICY_TYPE} one")
    for name in (WEIGHTS_FILE, *PROCESSOR_FILES):
        if not (folder / name).is_file():
            raise CheckpointError(f"{folder} has no {name}")
    return folder


def fingerprint(checkpoint: str | Path) -> str:
    """A digest of what decides the actions: config, weights, processor files (statistics), by content."""
    folder = Path(checkpoint).expanduser()
    processors = sorted(folder.glob("policy_*processor*"))
    return shared.fingerprint([folder / "config.json", folder / WEIGHTS_FILE, *processors])
