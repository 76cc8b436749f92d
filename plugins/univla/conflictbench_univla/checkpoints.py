"""What a UniVLA checkpoint folder and UniVLA's code must be, checked without torch (before a server is started).

A UniVLA LIBERO checkpoint, as UniVLA's fine-tuning writes it and its evaluation loads it: the VLA in Hugging Face
format (``config.json``, the weights, the processor's config, ``dataset_statistics.json``) and the action decoder's
weights, ``action_decoder.pt``, in the same folder. The model's code is in no package: it is UniVLA's own
(OpenDriveLab/UniVLA), read from a checkout named by ``UNIVLA_CODE``: the Hugging Face classes with
``predict_latent_action`` (``prismatic/extern/hf/``) and the decoder's attention pooling (``MAPBlock`` in
``prismatic/models/policy/transformer_utils.py``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from conflictbench_serving.checkpoints import CheckpointError
from conflictbench_serving.checkpoints import fingerprint as digest

__all__ = ["CODE_ENV", "CODE_FILES", "DECODER", "POLICY_TYPE", "CheckpointError", "check_checkpoint", "check_code"]

POLICY_TYPE = "univla"
CODE_ENV = "UNIVLA_CODE"
DECODER = "action_decoder.pt"
HF_CODE = "prismatic/extern/hf"
CODE_FILES = (
    f"{HF_CODE}/configuration_prismatic.py",
    f"{HF_CODE}/modeling_prismatic.py",
    f"{HF_CODE}/processing_prismatic.py",
    "prismatic/models/policy/transformer_utils.py",
)


def check_checkpoint(folder: str | Path) -> Path:
    """The folder, checked to hold a UniVLA checkpoint with its action decoder; :class:`CheckpointError` why not."""
    folder = Path(folder).expanduser()
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder}")
    try:
        config = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError) as error:
        raise CheckpointError(f"{folder} is not a UniVLA checkpoint (config.json: {error})") from None
    if not isinstance(config, dict) or config.get("model_type") != "openvla":
        raise CheckpointError(f"{folder}/config.json is not an OpenVLA-type model's (UniVLA's VLA is one)")
    if not any(folder.glob("*.safetensors")) and not any(folder.glob("pytorch_model*.bin")):
        raise CheckpointError(f"{folder} holds no weights (*.safetensors or pytorch_model*.bin)")
    if not (folder / DECODER).is_file():
        raise CheckpointError(f"{folder} lacks {DECODER}, the action decoder's weights (copy it beside the VLA)")
    return folder


def check_code(code: str | Path | None = None) -> Path:
    """UniVLA's checkout (``code``, else ``$UNIVLA_CODE``), checked to hold the files the server reads."""
    code = code or os.environ.get(CODE_ENV)
    if not code:
        raise CheckpointError(
            f"UniVLA's model code is in no package: set {CODE_ENV} to a checkout of OpenDriveLab/UniVLA "
            "(git clone https://github.com/OpenDriveLab/UniVLA)"
        )
    code = Path(code).expanduser()
    missing = [name for name in CODE_FILES if not (code / name).is_file()]
    if missing:
        raise CheckpointError(f"{CODE_ENV}={code} is not a UniVLA checkout (no {missing[0]})")
    return code


def fingerprint(folder: str | Path) -> str:
    """A digest of what decides the actions: config, weights, processor, statistics, the decoder's weights, any
    code in the folder, and the model files of UniVLA's checkout (``UNIVLA_CODE``)."""
    folder = Path(folder)
    code = check_code()
    files = [
        path
        for path in sorted(folder.iterdir())
        if path.is_file() and path.suffix in (".json", ".py", ".safetensors", ".bin", ".pt", ".model")
    ]
    return digest([*files, *(code / name for name in CODE_FILES)])
