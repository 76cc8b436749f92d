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

from pathlib import Path

from conflictbench_serving import lerobot
from conflictbench_serving.checkpoints import CheckpointError

__all__ = ["POLICY_TYPE", "CheckpointError", "check_checkpoint", "fingerprint"]

POLICY_TYPE = "groot"
_NOT_LEROBOT = " (an Isaac-GR00T checkpoint? serve it with NVIDIA's run_gr00t_server.py, then model.server=...)"


def check_checkpoint(checkpoint: str | Path) -> Path:
    """The folder, checked to hold a LeRobot GR00T checkpoint; :class:`CheckpointError` saying why not."""
    return lerobot.check_checkpoint(Path(checkpoint), [POLICY_TYPE], hint=_NOT_LEROBOT)


#: A digest of what decides the actions: config, weights, processor files (statistics), by content.
fingerprint = lerobot.checkpoint_fingerprint
