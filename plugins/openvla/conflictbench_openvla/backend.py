"""An OpenVLA checkpoint as a function of request rows (model environment only), as ``deploy.py`` runs it.

``deploy.py``'s steps, kept: the processor and model loaded from the checkpoint's own code
(``AutoProcessor`` / ``AutoModelForVision2Seq`` with ``trust_remote_code``), the model in bfloat16; for a local
folder, ``dataset_statistics.json`` as the model's ``norm_stats``; the image as a PIL RGB image (no other step:
the client has done the JPEG round trip, resize and crop); OpenVLA's prompt (the "v01" template for checkpoints
whose path says "v01", as deploy.py checks); the checkpoint's own ``predict_action(**inputs, unnorm_key=key,
do_sample=False)``, which generates the action tokens greedily, de-tokenizes and un-normalizes them
(``processing.detokenize`` and ``unnormalize`` restate it; the tests check that both agree). Greedy decoding
needs no seed. ``predict_action`` takes one row, so each distinct row is its own call (the copies padding a call
to its fixed shape are not run again). One difference: ``deploy.py`` asks for flash-attention 2 on its GPU; this
loads transformers' default attention (flash-attention is no dependency here and has no CPU kernel), so bfloat16
results can differ from ``deploy.py``'s in the last bits.

Imports torch and transformers only inside :func:`load_backend`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .checkpoints import POLICY_TYPE, CheckpointError, check_checkpoint, declared_transformers, fingerprint
from .processing import prompt

V01_SYSTEM_PROMPT = (
    "A chat between a curious user and an artificial intelligence assistant. "
    "The assistant gives helpful, detailed, and polite answers to the user's questions."
)


@dataclass(frozen=True)
class Row:
    """One request: the client's processed image (uint8 H x W x 3), the task text, the statistics key."""

    image: np.ndarray
    instruction: str
    unnorm_key: str | None


def v01_prompt(instruction: str) -> str:
    return f"{V01_SYSTEM_PROMPT} USER: What action should the robot take to {instruction.lower()}? ASSISTANT:"


class OpenVlaBackend:
    """One loaded checkpoint: :meth:`infer_batch` answers each distinct row with its own ``predict_action``."""

    def __init__(self, checkpoint: Path, processor: Any, model: Any, device: str, v01: bool = False) -> None:
        import torch
        import transformers

        self.torch, self.processor, self.model = torch, processor, model
        self.device, self.dtype = torch.device(device), torch.bfloat16
        self.prompt = v01_prompt if v01 else prompt
        self.metadata: dict = {
            "policy_type": POLICY_TYPE,
            "checkpoint": str(checkpoint),
            "checkpoint_fingerprint": fingerprint(checkpoint),
            "unnorm_keys": sorted(getattr(model, "norm_stats", {}) or {}),
            "transformers": transformers.__version__,
        }

    def infer(self, row: Row) -> np.ndarray:
        from PIL import Image

        keys = self.metadata["unnorm_keys"]
        if row.unnorm_key is not None and row.unnorm_key not in keys:
            raise KeyError(f"the checkpoint has no statistics {row.unnorm_key!r} (it has: {', '.join(keys)})")
        image = Image.fromarray(np.asarray(row.image, dtype=np.uint8)).convert("RGB")
        inputs = self.processor(self.prompt(row.instruction), image).to(self.device, dtype=self.dtype)
        with self.torch.inference_mode():
            action = self.model.predict_action(**inputs, unnorm_key=row.unnorm_key, do_sample=False)
        return np.asarray(action, dtype=np.float64)

    def infer_batch(self, rows: list[Row]) -> list[np.ndarray]:
        answers: dict[int, np.ndarray] = {}
        for row in rows:  # padding copies are the same object: answered once
            if id(row) not in answers:
                answers[id(row)] = self.infer(row)
        return [answers[id(row)] for row in rows]


def _same_minor(a: str, b: str) -> bool:
    return a.split(".")[:2] == b.split(".")[:2]


def load_backend(checkpoint: str | Path, device: str = "cpu") -> OpenVlaBackend:
    """Load ``checkpoint`` as ``deploy.py`` does; :class:`CheckpointError` for a folder that cannot be served here."""
    import torch
    import transformers
    from transformers import AutoModelForVision2Seq, AutoProcessor

    folder = check_checkpoint(checkpoint).resolve()
    declared = declared_transformers(folder)
    if declared is not None and not _same_minor(declared, transformers.__version__):
        raise CheckpointError(
            f"{folder} was written with transformers {declared}; this environment has {transformers.__version__}: "
            "build one with that version (pip install transformers==...) and point model.python= at it"
        )
    processor = AutoProcessor.from_pretrained(folder, trust_remote_code=True)
    model = AutoModelForVision2Seq.from_pretrained(
        folder, trust_remote_code=True, torch_dtype=torch.bfloat16, low_cpu_mem_usage=True
    ).to(device)
    model.eval()
    statistics = folder / "dataset_statistics.json"
    if statistics.is_file():
        model.norm_stats = json.loads(statistics.read_text())
    return OpenVlaBackend(folder, processor, model, device, v01="v01" in str(checkpoint))  # deploy.py: the path given
