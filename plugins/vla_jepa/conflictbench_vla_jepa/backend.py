"""A LeRobot VLA-JEPA checkpoint as a batch function of request rows (model environment only).

The server side of VLA-JEPA's split: its LIBERO client has already turned both images upright and resized them
to 224 (area), and built the 8-D state and the text; the server runs the model and answers the NORMALIZED chunk
(the client clips, snaps the gripper, un-normalizes). Here LeRobot runs the model with what the checkpoint
saved: ``from_pretrained`` of its config type and its preprocessor (state mean/std normalization); the
postprocessor is not applied, only its action statistics are read, for the metadata (the client un-normalizes
with them, as LeRobot's postprocessor would: clip, gripper to 0/1 at 0.5, min/max on every dimension).

Rows enter as LeRobot's environment path makes observations: HWC uint8 images become CHW float32 in [0, 1]
(Qwen3-VL's processor runs with ``do_rescale=False``) under LeRobot's LIBERO camera names
(``observation.images.image``, ``...image2`` for the wrist; the checkpoint's own names where it has two others,
wrist by name), ``task`` is the list of instructions.

Sampling depends on the request, never on the call order or batch company. LeRobot's ``predict_action_chunk``
ignores ``noise=``: the action head draws ``torch.randn(B, chunk_size, action_dim)`` itself
(``VLAJEPAActionHead.predict_action``), so a row's noise would be a slice of one draw for the whole batch. This
backend hands the head each row's own noise instead, drawn from a CPU generator seeded with the row's seed (0
when it has none): conflictbench-serving's :func:`~conflictbench_serving.seeding.seeded_draw`, which fails a
call in which the head does not draw exactly once.

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
    """One loaded checkpoint: :meth:`infer_batch` runs one forward pass for any number of rows."""

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
        """The normalized chunk (chunk_length, action_dim) float32 of each row; a row's chunk does not depend
        on the other rows (its noise comes from its own seed)."""
        import torch

        if not rows:
            return []

        def images(pick) -> Any:
            stacked = torch.from_numpy(np.stack([np.asarray(pick(row)) for row in rows]))
            return stacked.permute(0, 3, 1, 2).contiguous().to(torch.float32) / 255.0

        batch = {
            self.image_keys[0]: images(lambda row: row.image),
            self.image_keys[1]: images(lambda row: row.wrist_image),
            "observation.state": torch.from_numpy(np.stack([row.state for row in rows]).astype(np.float32)),
            "task": [row.instruction for row in rows],
        }
        noise = torch.stack([row_noise(row.seed, (self.chunk_length, self.action_dim)) for row in rows])
        with torch.inference_mode(), seeded_draw(self._head_module, noise):
            chunks = self._policy.predict_action_chunk(self._preprocessor(batch))
        chunks = chunks.to("cpu", torch.float32).numpy()
        return [np.array(chunk) for chunk in chunks]


def action_statistics(postprocessor) -> dict:
    """The min/max the checkpoint's postprocessor un-normalizes actions with, as the client reads them (every
    dimension un-normalized, as LeRobot does: its gripper snap comes first, so a -1..1 gripper range keeps 0/1)."""
    for step in postprocessor.steps:
        stats = getattr(step, "stats", None)
        if type(step).__name__.startswith("Unnormalizer") and stats and "action" in stats:
            low, high = (np.asarray(stats["action"][key], dtype=np.float64).reshape(-1) for key in ("min", "max"))
            return {"min": low.tolist(), "max": high.tolist(), "mask": [True] * len(low)}
    raise CheckpointError("the checkpoint's postprocessor has no min/max action statistics")


def load_backend(checkpoint: Path, device: str = "cpu") -> JepaBackend:
    """Load a LeRobot VLA-JEPA checkpoint folder with its saved processors; CheckpointError if not usable."""
    folder = check_checkpoint(checkpoint)
    config_json = json.loads((folder / "config.json").read_text())
    state = (config_json.get("input_features") or {}).get("observation.state") or {}
    if list(state.get("shape", [])) != [STATE_SIZE]:
        raise CheckpointError(f"{folder} takes a state of shape {state.get('shape')}; the client sends {STATE_SIZE}")

    policy, preprocessor, postprocessor = load_policy(folder, POLICY_TYPE, device)
    return JepaBackend(folder, policy, preprocessor, action_statistics(postprocessor), device)
