"""What a VLA-JEPA checkpoint folder must hold, checked without torch (the client checks before starting a server).

A LeRobot ``vla_jepa`` checkpoint is a folder with ``config.json`` (``"type": "vla_jepa"``), ``model.safetensors``
and the processor pipelines (``policy_preprocessor.json``, ``policy_postprocessor.json`` and their state files:
the normalization statistics), as ``save_pretrained`` writes them. VLA-JEPA's own training runs (starVLA's
``checkpoints/steps_N_pytorch_model.pt`` with ``config.yaml`` and ``dataset_statistics.json``) are not LeRobot
checkpoints: serve those with upstream's ``server_policy.py`` and point ``model.server`` at it.
"""

from __future__ import annotations

from pathlib import Path

from conflictbench_serving import lerobot
from conflictbench_serving.checkpoints import CheckpointError

__all__ = ["POLICY_TYPE", "CheckpointError", "check_checkpoint", "fingerprint"]

POLICY_TYPE = "vla_jepa"
_NOT_LEROBOT = " (a VLA-JEPA training run? serve it with upstream's server_policy.py, then model.server=...)"


def check_checkpoint(checkpoint: str | Path) -> Path:
    """The folder, checked to hold a LeRobot VLA-JEPA checkpoint; :class:`CheckpointError` saying why not."""
    return lerobot.check_checkpoint(Path(checkpoint), [POLICY_TYPE], hint=_NOT_LEROBOT)


#: A digest of what decides the actions: config, weights, processor files (statistics), by content.
fingerprint = lerobot.checkpoint_fingerprint
