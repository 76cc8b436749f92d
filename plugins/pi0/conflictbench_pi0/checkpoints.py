"""What a π checkpoint folder must hold, checked without torch (the client checks before starting a server).

A LeRobot π checkpoint is a folder with ``config.json`` (its ``type`` is ``pi0``, ``pi05`` or
``pi0_fast``) and ``model.safetensors``, as ``PreTrainedPolicy.save_pretrained`` writes it (the
normalization statistics sit beside them in the processor files).
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

#: conflictbench's policy names and the LeRobot config ``type`` each loads.
POLICY_TYPES = {"pi0": "pi0", "pi05": "pi05", "pi0-fast": "pi0_fast"}
WEIGHTS_FILE = "model.safetensors"
#: Where a checkpoint can be loaded (``model.device``, ``serve --device``).
DEVICE = re.compile(r"auto|cpu|cuda(:\d+)?")


class CheckpointError(Exception):
    """The folder is not a usable π checkpoint (the message is one line for the user)."""


def checkpoint_type(checkpoint: str | Path) -> str:
    """The LeRobot policy type of the checkpoint folder; :class:`CheckpointError` if it is not a π one."""
    folder = Path(checkpoint).expanduser()
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder}")
    config = folder / "config.json"
    try:
        kind = json.loads(config.read_text()).get("type")
    except FileNotFoundError:
        raise CheckpointError(f"{folder} is not a LeRobot checkpoint (no config.json)") from None
    except (OSError, ValueError, AttributeError) as exc:
        raise CheckpointError(f"cannot read {config}: {exc}") from None
    if kind not in POLICY_TYPES.values():
        raise CheckpointError(f"{folder} holds a {kind or 'untyped'} policy, not a π one (pi0, pi05, pi0_fast)")
    if not (folder / WEIGHTS_FILE).is_file():
        raise CheckpointError(f"{folder} has no {WEIGHTS_FILE}")
    return kind


def check_checkpoint(checkpoint: str | Path, policy: str) -> Path:
    """The folder, checked to hold a checkpoint of ``policy`` (pi0, pi05 or pi0-fast)."""
    kind = checkpoint_type(checkpoint)
    if kind != POLICY_TYPES[policy]:
        wanted = next(name for name, t in POLICY_TYPES.items() if t == kind)
        raise CheckpointError(f"{checkpoint} is a {kind} checkpoint: use model={wanted}, not model={policy}")
    return Path(checkpoint).expanduser()


def fingerprint(checkpoint: str | Path) -> str:
    """A digest of what decides the model's actions: the config, the weights and the processor files
    (normalization statistics), by content. The same weights under another path give the same digest;
    new weights written to the same path give another. Reads every byte (a 7 GB checkpoint: seconds)."""
    folder = Path(checkpoint).expanduser()
    digest = hashlib.sha256()
    files = [folder / "config.json", folder / WEIGHTS_FILE, *sorted(folder.glob("policy_*processor*"))]
    for path in files:
        digest.update(f"{path.name}\0".encode())
        with open(path, "rb") as handle:
            digest.update(hashlib.file_digest(handle, "sha256").digest())
    return f"sha256:{digest.hexdigest()[:24]}"
