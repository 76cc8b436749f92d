"""A UniVLA checkpoint as a function of request rows (model environment only), as UniVLA's LIBERO evaluation runs it.

UniVLA's steps, kept (``experiments/robot/libero/run_libero_eval.py``, ``experiments/robot/openvla_utils.py``):
UniVLA's Hugging Face classes registered with the auto classes and the VLA loaded in bfloat16, the checkpoint's
``dataset_statistics.json`` as its ``norm_stats``; the image as a PIL RGB image (the client has done the JPEG round
trip, resize and crop); the prompt with the history; ``predict_latent_action(**inputs, unnorm_key=key,
do_sample=True, temperature=0.75, top_p=0.9)``; the action decoder (``ActionDecoderHead``: two attention poolings,
a linear layer to ``7 x window`` and tanh, in float32) on the latent tokens' and the image's hidden states. The
decoder's ensembling window, history and un-normalization are the client's (stateless server).

UniVLA's code comes from the user's checkout (``UNIVLA_CODE``), loaded by file: ``prismatic/__init__.py`` imports
UniVLA's whole training stack, which the model does not need. Sampling is seeded per request (torch's global
generator, right before the row's call, in the one model thread): a row's tokens depend on its episode and step,
never on the call order (upstream seeds once per run, so its samples depend on every query before). Two more
differences (docs/upstream/audit_univla.md): UniVLA's ``get_vla`` asks for flash-attention 2, which has no CPU
kernel and is no dependency here, so this loads transformers' default attention; and it ran on torch 2.2.0 where
the model environment has the LeRobot environments' torch. Both move bfloat16 results in the last bits, and a
sampled token can change with them.

Imports torch and transformers only inside :func:`load_backend`.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from conflictbench_serving.checkpoints import reduce_seed

from .checkpoints import DECODER, HF_CODE, POLICY_TYPE, CheckpointError, check_checkpoint, check_code, fingerprint
from .processing import LATENT_TOKENS, prompt

PACKAGE = "univla_code"  # the name UniVLA's Hugging Face modules are loaded under (their relative imports need one)


@dataclass(frozen=True)
class Row:
    image: np.ndarray
    instruction: str
    history: str
    unnorm_key: str
    seed: int | None


def _load_module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def load_code(code: Path) -> dict[str, Any]:
    """UniVLA's classes from its checkout, without its package's imports."""
    import types

    package = types.ModuleType(PACKAGE)
    package.__path__ = [str(code / HF_CODE)]
    sys.modules[PACKAGE] = package
    modules = {
        name: _load_module(f"{PACKAGE}.{name}", code / HF_CODE / f"{name}.py")
        for name in ("configuration_prismatic", "modeling_prismatic", "processing_prismatic")
    }
    utils = _load_module("univla_transformer_utils", code / "prismatic/models/policy/transformer_utils.py")
    return {
        "OpenVLAConfig": modules["configuration_prismatic"].OpenVLAConfig,
        "OpenVLAForActionPrediction": modules["modeling_prismatic"].OpenVLAForActionPrediction,
        "PrismaticImageProcessor": modules["processing_prismatic"].PrismaticImageProcessor,
        "PrismaticProcessor": modules["processing_prismatic"].PrismaticProcessor,
        "MAPBlock": utils.MAPBlock,
    }


def decoder_head(map_block: type, window: int):
    """UniVLA's ``ActionDecoderHead`` (its evaluation script defines it): the latent tokens pooled with the pooled
    image as the initial embedding, then ``Linear(512, 7 * window)`` and tanh."""
    import torch

    class ActionDecoderHead(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.latent_action_pool = map_block(n_latents=1, vis_dim=4096, embed_dim=512, n_heads=8)
            self.visual_pool = map_block(n_latents=1, vis_dim=4096, embed_dim=512, n_heads=8)
            self.proj = torch.nn.Sequential(torch.nn.Linear(512, 7 * window), torch.nn.Tanh())

        def forward(self, latent_action_tokens, visual_embed):
            pooled_image = self.visual_pool(visual_embed)
            return self.proj(self.latent_action_pool(latent_action_tokens[:, -4:], init_embed=pooled_image))

    return ActionDecoderHead()


def model_inputs(row: Row, checkpoint: str = "") -> tuple[str, Any]:
    """The prompt and the PIL image handed to the processor for ``row``, the checkpoint named ``checkpoint``: UniVLA's
    ``get_vla_latent_action`` (``experiments/robot/openvla_utils.py:176-213``) after the client's image steps."""
    from PIL import Image

    text = prompt(row.instruction, row.history, v01="openvla-v01" in checkpoint)  # upstream: the path as given
    return text, Image.fromarray(np.asarray(row.image, np.uint8)).convert("RGB")


def reply_of(head_output: Any, generated_ids: Any, window: int) -> dict[str, np.ndarray]:
    """The reply for the action decoder's output (a float32 tensor, or an array, of ``7 * window`` values a row) and
    ``predict_latent_action``'s ids: as UniVLA's ``ActionDecoder.forward`` reads it (``run_libero_eval.py:142-143``:
    reshaped to ``(-1, window, 7)`` and read through ``.tolist()``, so float64 holding the float32 values
    exactly), its first row; the ids as int64, the last four (``predict_latent_action`` returns at most four)."""
    chunk = np.array(head_output.reshape(-1, window, 7)[0].tolist(), dtype=np.float64)
    tokens = np.asarray(generated_ids[0].tolist(), dtype=np.int64).reshape(-1)[-LATENT_TOKENS:]
    return {"actions": chunk, "latent_tokens": tokens}


def action_statistics(norm_stats: dict) -> dict[str, dict]:
    """``/metadata``'s ``action_statistics``: per key, the ``q01``, ``q99`` and ``mask`` of its ``action`` entry, as
    JSON gave them (UniVLA's loop reads ``model.get_action_stats(key)``, ``run_libero_eval.py:326-328``)."""
    return {
        key: {name: entry["action"][name] for name in ("q01", "q99", "mask") if name in entry["action"]}
        for key, entry in norm_stats.items()
        if isinstance(entry, dict) and "action" in entry
    }


class UnivlaBackend:
    """One loaded checkpoint: :meth:`infer_batch` answers each distinct row with its own seeded call."""

    def __init__(
        self, checkpoint: Path, processor: Any, vla: Any, decoder: Any, window: int, device: str, given: str = ""
    ) -> None:
        import torch

        self.torch, self.processor, self.vla, self.decoder = torch, processor, vla, decoder
        self.device, self.window, self.given = torch.device(device), window, given or str(checkpoint)
        self.metadata: dict = {
            "policy_type": POLICY_TYPE,
            "checkpoint": str(checkpoint),
            "checkpoint_fingerprint": fingerprint(checkpoint),
            "window": window,
            "action_statistics": action_statistics(getattr(vla, "norm_stats", {}) or {}),
        }

    def infer(self, row: Row) -> dict[str, np.ndarray]:
        torch = self.torch
        text, image = model_inputs(row, self.given)
        inputs = self.processor(text, image).to(self.device, dtype=torch.bfloat16)
        torch.manual_seed(reduce_seed(row.seed))
        with torch.inference_mode():
            latent_action, visual_embed, generated_ids = self.vla.predict_latent_action(
                **inputs, unnorm_key=row.unnorm_key, do_sample=True, temperature=0.75, top_p=0.9
            )
            chunk = self.decoder(latent_action.to(torch.float), visual_embed.to(torch.float))
        return reply_of(chunk, generated_ids, self.window)

    def infer_batch(self, rows: list[Row]) -> list[dict]:
        answers: dict[int, dict] = {}
        for row in rows:  # padding copies are the same object: answered once
            if id(row) not in answers:
                answers[id(row)] = self.infer(row)
        return [answers[id(row)] for row in rows]


def load_backend(checkpoint: str | Path, device: str = "cpu") -> UnivlaBackend:
    """Load ``checkpoint`` as UniVLA's evaluation does; :class:`CheckpointError` for what cannot be served."""
    import torch
    from transformers import AutoConfig, AutoImageProcessor, AutoModelForVision2Seq, AutoProcessor

    folder = check_checkpoint(checkpoint).resolve()
    classes = load_code(check_code())
    torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = True, False  # as UniVLA's set_seed_everywhere
    AutoConfig.register("openvla", classes["OpenVLAConfig"])  # as UniVLA's get_vla does
    AutoImageProcessor.register(classes["OpenVLAConfig"], classes["PrismaticImageProcessor"])
    AutoProcessor.register(classes["OpenVLAConfig"], classes["PrismaticProcessor"])
    AutoModelForVision2Seq.register(classes["OpenVLAConfig"], classes["OpenVLAForActionPrediction"])
    processor = AutoProcessor.from_pretrained(folder, trust_remote_code=True)
    vla = AutoModelForVision2Seq.from_pretrained(
        folder, torch_dtype=torch.bfloat16, low_cpu_mem_usage=True, trust_remote_code=True
    ).to(device)
    vla.eval()
    statistics = folder / "dataset_statistics.json"
    if statistics.is_file():
        vla.norm_stats = json.loads(statistics.read_text())
    try:
        state = torch.load(folder / DECODER, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises several types for a file that is no state dict
        problem = f"{folder / DECODER} is not an ActionDecoderHead's state dict ({type(error).__name__})"
        raise CheckpointError(problem) from None
    if not isinstance(state, dict) or "proj.0.weight" not in state:
        raise CheckpointError(f"{folder / DECODER} is not an ActionDecoderHead's state dict (no proj.0.weight)")
    rows = state["proj.0.weight"].shape[0]
    if rows % 7:
        raise CheckpointError(f"{folder / DECODER}: its projection gives {rows} values, not 7 per step")
    decoder = decoder_head(classes["MAPBlock"], rows // 7)
    try:
        decoder.load_state_dict(state)
    except RuntimeError as error:  # keys or shapes of another module (a "net." or "module." prefix, ...)
        first = str(error).strip().splitlines()[0]
        raise CheckpointError(f"{folder / DECODER} does not fit UniVLA's ActionDecoderHead: {first}") from None
    return UnivlaBackend(folder, processor, vla, decoder.to(device).eval(), rows // 7, device, str(checkpoint))
