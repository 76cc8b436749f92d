"""What a GR00T N1.7 checkpoint folder must hold, checked without torch (the client checks before starting a server).

A LeRobot ``groot`` checkpoint is a folder with ``config.json`` (``"type": "groot"``), ``model.safetensors`` and
the processor pipelines (``policy_preprocessor.json``, ``policy_postprocessor.json`` and their state files:
the state and action min/max), as ``save_pretrained`` writes them. Loading it also reads its base model
(``base_model_path`` in the config, ``nvidia/GR00T-N1.7-3B`` by default) and the processor of
``nvidia/Cosmos-Reason2-2B`` from the Hugging Face cache (downloaded once where the hub is reachable). A
checkpoint of NVIDIA's own Isaac-GR00T training is not a LeRobot one: serve it with NVIDIA's
``run_gr00t_server.py`` and point ``model.server`` at it.
"""

from __future__ import annotations

import json
from pathlib import Path

from conflictbench_serving import checkpoints as shared
from conflictbench_serving.checkpoints import CheckpointError

__all__ = ["POLICY_TYPE", "CheckpointError", "check_checkpoint", "fingerprint"]

POLICY_TYPE = "groot"
WEIGHTS_FILE = "model.safetensors"
PROCESSOR_FILES = ("policy_preprocessor.json", "policy_postprocessor.json")


def check_checkpoint(checkpoint: str | Path) -> Path:
    """The folder, checked to hold a LeRobot GR00T checkpoint; :class:`CheckpointError` saying why not."""
    folder = Path(checkpoint).expanduser()
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder}")
    config = folder / "config.json"
    try:
        kind = json.loads(config.read_text()).get("type")
    except FileNotFoundError:
        hint = " (an Isaac-GR00T checkpoint? serve it with NVIDIA's run_gr00t_server.py, then model.server=...)"
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
