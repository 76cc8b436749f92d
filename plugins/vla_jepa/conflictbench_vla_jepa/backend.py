"""A LeRobot VLA-JEPA checkpoint as a function of request rows (model environment only).

The server side of VLA-JEPA's split: its LIBERO client has already turned both images upright and resized them
to 224 (area), and built the 8-D state and the text; the server runs the model and answers the NORMALIZED chunk
(the client clips, snaps the gripper, un-normalizes). Here LeRobot runs the model with what the checkpoint
saved: ``from_pretrained`` of its config type and its preprocessor (state mean/std normalization); the
postprocessor is not applied, only its action statistics are read, for the metadata (the client un-normalizes
with them, as LeRobot's postprocessor would: clip, gripper to 0/1 at 0.5, min/max on every dimension; a
checkpoint configured to post-process otherwise is refused, :func:`check_postprocessing`).

Rows enter as LeRobot's environment path makes observations: HWC uint8 images become CHW float32 in [0, 1]
(Qwen3-VL's processor runs with ``do_rescale=False``) under LeRobot's LIBERO camera names
(``observation.images.image``, ``...image2`` for the wrist; the checkpoint's own names where it has two others,
wrist by name), ``task`` is the list of instructions.

Sampling depends on the request, never on the call order or batch company. Each distinct row runs as its own
forward pass: the Qwen processor left-pads a batch's prompts to the longest (LeRobot's ``tokenizer_padding_side``
"left"), which would move a row's actions with its company's text (rows of one call run one after another; the
copies padding a call to its fixed shape are not run again). And LeRobot's ``predict_action_chunk`` ignores
``noise=``: the action head draws ``torch.randn(B, chunk_size, action_dim)`` itself
(``VLAJEPAActionHead.predict_action``), from torch's global generator. This backend hands the head the row's own
noise instead, drawn from a CPU generator seeded with the row's seed (0 when it has none): conflictbench-serving's
:func:`~conflictbench_serving.seeding.seeded_draw`, which fails a call in which the head does not draw exactly once.

Imports torch and LeRobot only inside :func:`load_backend`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from conflictbench_serving.lerobot import camera_order, load_policy
from conflictbench_serving.seeding import row_noise, seeded_draw

from .checkpoints import POLICY_TYPE, CheckpointError, check_checkpoint, fingerprint
from .protocol import STATE_SIZE, Row


class JepaBackend:
    """One loaded checkpoint: :meth:`infer_batch` answers each distinct row with its own forward pass."""

    def __init__(self, checkpoint: Path, policy, preprocessor, action_statistics: dict, device: str) -> None:
        import lerobot
        from lerobot.policies.vla_jepa import action_head

        config = policy.config
        self.chunk_length = int(config.chunk_size)
        self.action_dim = int(config.output_features["action"].shape[0])
        cameras = [n for n, f in config.input_features.items() if f.type.value.endswith("VISUAL")]
        if len(cameras) != 2:
            raise CheckpointError(f"{checkpoint} takes {len(cameras)} camera images; VLA-JEPA's LIBERO client sends 2")
        self.image_keys = camera_order(cameras)
        self.metadata: dict = {
            "policy_type": POLICY_TYPE,
            "checkpoint": str(checkpoint),
            "checkpoint_fingerprint": fingerprint(checkpoint),
            "chunk_length": self.chunk_length,
            "action_dim": self.action_dim,
            "action_statistics": action_statistics,
            "image_keys": list(self.image_keys),
            "lerobot_version": str(lerobot.__version__),
        }
        self._policy, self._preprocessor, self._device = policy, preprocessor, device
        self._head_module = action_head

    def infer_batch(self, rows: list[Row]) -> list[np.ndarray]:
        """The normalized chunk (chunk_length, action_dim) float32 of each row, each distinct row in its own
        forward pass (the copies padding a call are not run again): the Qwen processor left-pads a batch's
        prompts to the longest, which would move a row's actions with its company's text."""
        chunks: dict[int, np.ndarray] = {}
        for row in rows:
            if id(row) not in chunks:
                chunks[id(row)] = self.normalized_chunk(row)
        return [chunks[id(row)] for row in rows]

    def normalized_chunk(self, row: Row) -> np.ndarray:
        """One row's normalized chunk: LeRobot's preprocessor and model, the row's own seeded noise."""
        import torch

        def image(array: np.ndarray) -> Any:
            return torch.from_numpy(np.ascontiguousarray(array)).permute(2, 0, 1)[None].to(torch.float32) / 255.0

        batch = {
            self.image_keys[0]: image(row.image),
            self.image_keys[1]: image(row.wrist_image),
            "observation.state": torch.from_numpy(row.state.astype(np.float32))[None],
            "task": [row.instruction],
        }
        noise = row_noise(row.seed, (self.chunk_length, self.action_dim))[None]
        with torch.inference_mode(), seeded_draw(self._head_module, noise):
            chunk = self._policy.predict_action_chunk(self._preprocessor(batch))
        return chunk.to("cpu", torch.float32).numpy()[0]


def action_statistics(postprocessor) -> dict:
    """The min/max the checkpoint's postprocessor un-normalizes actions with, as the client reads them (every
    dimension un-normalized, as LeRobot does: its gripper snap comes first, so a -1..1 gripper range keeps 0/1)."""
    for step in postprocessor.steps:
        stats = getattr(step, "stats", None)
        if type(step).__name__.startswith("Unnormalizer") and stats and "action" in stats:
            low, high = (np.asarray(stats["action"][key], dtype=np.float64).reshape(-1) for key in ("min", "max"))
            return {"min": low.tolist(), "max": high.tolist(), "mask": [True] * len(low)}
    raise CheckpointError("the checkpoint's postprocessor has no min/max action statistics")


#: The postprocessing the client restates (VLA-JEPA's LIBERO client, and LeRobot's defaults): a checkpoint
#: configured otherwise would be un-normalized wrongly on the client, and its actions scored as its behaviour.
CLIENT_POSTPROCESSING = {
    "clip_normalized_actions": True,
    "pre_snap_gripper_action": True,
    "binarize_gripper_action": True,
    "gripper_dim": 6,
    "gripper_threshold": 0.5,
}


def check_postprocessing(folder: Path, config: Any) -> None:
    """CheckpointError unless the checkpoint post-processes actions as the client does (min/max, defaults)."""
    for name, wanted in CLIENT_POSTPROCESSING.items():
        if getattr(config, name, wanted) != wanted:
            raise CheckpointError(
                f"{folder} sets {name}={getattr(config, name)!r}; the VLA-JEPA client does {wanted!r}"
            )
    mode = getattr(config.normalization_mapping.get("ACTION"), "value", config.normalization_mapping.get("ACTION"))
    if str(mode) != "MIN_MAX":
        raise CheckpointError(f"{folder} normalizes actions with {mode}; the VLA-JEPA client un-normalizes min/max")


def load_backend(checkpoint: Path, device: str = "cpu") -> JepaBackend:
    """Load a LeRobot VLA-JEPA checkpoint folder with its saved processors; CheckpointError if not usable."""
    folder = check_checkpoint(checkpoint)
    config_json = json.loads((folder / "config.json").read_text())
    state = (config_json.get("input_features") or {}).get("observation.state") or {}
    if list(state.get("shape", [])) != [STATE_SIZE]:
        raise CheckpointError(f"{folder} takes a state of shape {state.get('shape')}; the client sends {STATE_SIZE}")

    policy, preprocessor, postprocessor = load_policy(folder, POLICY_TYPE, device)
    check_postprocessing(folder, policy.config)
    return JepaBackend(folder, policy, preprocessor, action_statistics(postprocessor), device)
