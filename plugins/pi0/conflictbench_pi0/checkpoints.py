"""What a π checkpoint folder must hold, checked without torch (the client checks before starting a server).

A LeRobot π checkpoint is a folder with ``config.json`` (its ``type`` is ``pi0``, ``pi05`` or
``pi0_fast``) and ``model.safetensors``, as ``PreTrainedPolicy.save_pretrained`` writes it (the
normalization statistics sit beside them in the processor files).
"""

from __future__ import annotations

from pathlib import Path

from conflictbench_serving import lerobot
from conflictbench_serving.checkpoints import CheckpointError

__all__ = ["POLICY_TYPES", "WEIGHTS_FILE", "CheckpointError", "check_checkpoint", "checkpoint_type", "fingerprint"]

#: conflictbench's policy names and the LeRobot config ``type`` each loads.
POLICY_TYPES = {"pi0": "pi0", "pi05": "pi05", "pi0-fast": "pi0_fast"}
WEIGHTS_FILE = "model.safetensors"


def checkpoint_type(checkpoint: str | Path) -> str:
    """The LeRobot policy type of the checkpoint folder; :class:`CheckpointError` if it is not a π one."""
    folder = Path(checkpoint).expanduser()
    kind = lerobot.checkpoint_type(folder)
    if kind not in POLICY_TYPES.values():
        raise CheckpointError(f"{folder} holds a {kind} policy, not a π one (pi0, pi05, pi0_fast)")
    if not (folder / WEIGHTS_FILE).is_file():
        raise CheckpointError(f"{folder} has no {WEIGHTS_FILE}")
    return kind


def check_checkpoint(checkpoint: str | Path, policy: str, option: str = "model=") -> Path:
    """The folder, checked to hold a checkpoint of ``policy`` (pi0, pi05 or pi0-fast); ``option`` is how the
    user names the policy where it is wrong (``model=`` in a run, ``--policy`` for the serve command)."""
    kind = checkpoint_type(checkpoint)
    if kind != POLICY_TYPES[policy]:
        wanted = next(name for name, t in POLICY_TYPES.items() if t == kind)
        raise CheckpointError(f"{checkpoint} is a {kind} checkpoint: use {option}{wanted}, not {option}{policy}")
    return Path(checkpoint).expanduser()


def fingerprint(checkpoint: str | Path) -> str:
    """A digest of what decides the model's actions: the config, the weights and the processor files
    (normalization statistics), by content."""
    return lerobot.checkpoint_fingerprint(Path(checkpoint))
