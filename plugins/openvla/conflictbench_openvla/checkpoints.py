"""What an OpenVLA checkpoint folder must hold, checked without torch (the client checks before starting a server).

An OpenVLA checkpoint in Hugging Face format, as ``openvla/openvla-7b-finetuned-libero-*`` are and OpenVLA's
fine-tuning writes them: ``config.json`` whose ``auto_map`` names the model class for ``AutoModelForVision2Seq``
in a Python file beside it (the checkpoint's own code, loaded with ``trust_remote_code``), the processor's
config, the weights, and for a local fine-tune ``dataset_statistics.json`` (the ``unnorm_key`` statistics; read
as ``deploy.py`` reads them). OpenVLA-OFT checkpoints also need their action head and proprio projector,
whose classes live only in moojink/openvla-oft's code: those are served by OFT's own ``deploy.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

from conflictbench_serving.checkpoints import CheckpointError
from conflictbench_serving.checkpoints import fingerprint as digest

__all__ = [
    "MODEL_AUTO_CLASS",
    "POLICY_TYPE",
    "CheckpointError",
    "check_checkpoint",
    "declared_transformers",
    "fingerprint",
]

POLICY_TYPE = "openvla"  # what our server's metadata says it hosts
MODEL_AUTO_CLASS = "AutoModelForVision2Seq"
WEIGHTS = ("*.safetensors", "pytorch_model*.bin")
OFT_NEEDS = (
    "an OpenVLA-OFT checkpoint is served by OFT's own vla-scripts/deploy.py (its action head and proprio projector "
    "need moojink/openvla-oft's code and its transformers fork, moojink/transformers-openvla-oft): start it with "
    "--num_images_in_input 2 --unnorm_key KEY and give model.server=http://HOST:8777"
)


def _config(folder: Path) -> dict:
    try:
        config = json.loads((folder / "config.json").read_text())
    except (OSError, ValueError) as error:
        raise CheckpointError(f"{folder} is not an OpenVLA checkpoint (config.json: {error})") from None
    if not isinstance(config, dict):
        raise CheckpointError(f"{folder}/config.json is not a JSON object")
    return config


def check_checkpoint(folder: str | Path, policy: str = "openvla") -> Path:
    """The folder, checked to hold an OpenVLA checkpoint with its own model code; :class:`CheckpointError` why not."""
    folder = Path(folder).expanduser()
    if policy == "openvla-oft":
        raise CheckpointError(OFT_NEEDS)
    if not folder.is_dir():
        raise CheckpointError(f"no checkpoint folder at {folder}")
    config = _config(folder)
    target = (config.get("auto_map") or {}).get(MODEL_AUTO_CLASS)
    if not isinstance(target, str) or "." not in target:
        raise CheckpointError(
            f"{folder}/config.json has no auto_map entry for {MODEL_AUTO_CLASS}: not an OpenVLA checkpoint in "
            "Hugging Face format (a Prismatic training run? convert it with OpenVLA's "
            "vla-scripts/extern/convert_openvla_weights_to_hf.py)"
        )
    module = target.split("--")[-1].rsplit(".", 1)[0]
    if not (folder / f"{module}.py").is_file():
        raise CheckpointError(f"{folder} lacks {module}.py, the model code its config.json names ({target})")
    if not any(folder.glob(pattern) for pattern in WEIGHTS):
        raise CheckpointError(f"{folder} holds no weights (*.safetensors or pytorch_model*.bin)")
    if not any((folder / name).is_file() for name in ("preprocessor_config.json", "processor_config.json")):
        raise CheckpointError(f"{folder} lacks the processor's config (preprocessor_config.json)")
    return folder


def declared_transformers(folder: str | Path) -> str | None:
    """The transformers version the checkpoint was written with (``config.json``'s ``transformers_version``)."""
    version = _config(Path(folder)).get("transformers_version")
    return version if isinstance(version, str) else None


def fingerprint(folder: str | Path) -> str:
    """A digest of what decides the actions: config, code, weights, processor, tokenizer and statistics files."""
    folder = Path(folder)
    files = [
        path
        for path in sorted(folder.iterdir())
        if path.is_file() and (path.suffix in (".json", ".py", ".safetensors", ".bin", ".model", ".txt"))
    ]
    return digest(files)
