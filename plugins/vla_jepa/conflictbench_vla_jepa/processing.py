"""What VLA-JEPA's LIBERO client does around the model, step by step (pinned by ``tests/test_vla_jepa_processing.py``).

The facts, from VLA-JEPA's ``examples/LIBERO/eval_libero.py`` and ``examples/LIBERO/model2libero_interface.py``:

- **client**: both cameras rotated 180 degrees (LIBERO renders upside down), then ``cv2.resize`` with
  ``INTER_AREA`` to 224 x 224 (agentview first, then the wrist camera); LIBERO's 8-D state (position,
  axis-angle, two gripper joint positions); the task text as it is (the server applies its own template);
- **server**: the model's ``predict_action`` answers a NORMALIZED chunk;
- **client**, on the reply, in the reply's own dtype (float32 from a server) as upstream computes it
  (``model2libero_interface.py:136-147`` at ginwind/VLA-JEPA@ec8c70f): clipped to [-1, 1]; the gripper (dimension 6)
  thresholded to 0 / 1 at 0.5; ``0.5 * (a + 1)`` still in the reply's dtype, then ``* (max - min) + min`` in float64
  (the statistics come from JSON), on the dimensions the statistics' ``mask`` keeps (all where it has none), with the
  statistics of ``unnorm_key`` in the checkpoint's ``dataset_statistics.json`` (the only key when none is given);
  then (``eval_libero.py:207-221``) each part cast to float32 and LIBERO's gripper ``1 - 2 (g > 0.5)`` of the float32
  value (open 1 -> -1): the executed action is float32's, ``.tolist()``-ed; the chunk's first
  ``future_action_window_size + 1`` rows (7 or 8, from the checkpoint's ``config.yaml``) executed before asking
  again;
- **episodes**: 10 no-op warm-up steps (conflictbench's default) and 250 / 280 / 300 / 520 policy steps for
  libero_spatial / object / goal / 10 (``eval_libero.py`` at ec8c70f; its earlier revisions gave libero_spatial
  400 at 6e4846c, then 200 at c3d2fde).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

IMAGE_SIZE = 224
MAX_STEPS = {"libero_spatial": 250, "libero_object": 280, "libero_goal": 300, "libero_10": 520}


def camera_image(rendered: np.ndarray) -> np.ndarray:
    """One camera as the client sends it: turned upright, then area-resized to 224 x 224, uint8."""
    upright = np.ascontiguousarray(rendered[::-1, ::-1])
    return cv2.resize(upright, (IMAGE_SIZE, IMAGE_SIZE), interpolation=cv2.INTER_AREA)


class StatisticsError(ValueError):
    """A statistics file that cannot be used; the message is one line for the user."""


@dataclass(frozen=True)
class ActionStatistics:
    """The action statistics the client un-normalizes with: ``low``/``high`` per dimension, and the mask."""

    low: np.ndarray
    high: np.ndarray
    mask: np.ndarray

    @classmethod
    def from_mapping(cls, action: dict) -> ActionStatistics:
        try:
            low, high = np.asarray(action["min"], dtype=np.float64), np.asarray(action["max"], dtype=np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise StatisticsError(f"the action statistics need numeric 'min' and 'max' lists ({exc})") from None
        mask = np.asarray(action.get("mask", np.ones(low.shape, dtype=bool)), dtype=bool)
        if low.shape != high.shape or low.shape != mask.shape or low.ndim != 1 or len(low) != 7:
            shapes = f"{low.shape}, {high.shape}, {mask.shape}"
            raise StatisticsError(f"the action statistics need 7 values each (min, max, mask), got {shapes}")
        return cls(low, high, mask)

    @classmethod
    def from_file(cls, path: str | Path, unnorm_key: str | None = None) -> ActionStatistics:
        """``[unnorm_key]["action"]`` of a ``dataset_statistics.json`` (the only key when ``unnorm_key`` is None)."""
        try:
            stats = json.loads(Path(path).expanduser().read_text())
        except (OSError, ValueError) as exc:
            raise StatisticsError(f"cannot read the statistics file {path}: {exc}") from None
        if not isinstance(stats, dict) or not stats:
            raise StatisticsError(f"{path} holds no dataset statistics")
        if unnorm_key is None:
            if len(stats) != 1:
                raise StatisticsError(f"{path} has statistics of {len(stats)} datasets: choose one with "
                                      f"model.unnorm_key ({', '.join(sorted(stats))})")  # fmt: skip
            unnorm_key = next(iter(stats))
        if unnorm_key not in stats or "action" not in stats[unnorm_key]:
            known = ", ".join(sorted(stats))
            raise StatisticsError(f"{path} has no action statistics for {unnorm_key!r} (has: {known})")
        return cls.from_mapping(stats[unnorm_key]["action"])


def chunk_length_from_config(path: str | Path) -> int:
    """``framework.action_model.future_action_window_size + 1`` of a VLA-JEPA run's ``config.yaml``."""
    import yaml

    try:
        config = yaml.safe_load(Path(path).read_text())
        return int(config["framework"]["action_model"]["future_action_window_size"]) + 1
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise StatisticsError(f"cannot read the chunk length from {path}: {exc}") from None


def unnormalize(normalized: np.ndarray, stats: ActionStatistics) -> np.ndarray:
    """Upstream's ``unnormalize_actions`` step by step, dtypes included: clip and the gripper's snap to 0 / 1 at 0.5
    in the reply's dtype, ``0.5 * (a + 1)`` too, then ``* (max - min) + min`` in float64 where ``mask`` says (the
    rest keep the reply's values); float64 out (a float32 reply's values are not rounded yet)."""
    actions = np.clip(normalized, -1, 1)  # python scalars: the reply's dtype stays (float32 from a server)
    actions[:, 6] = np.where(actions[:, 6] < 0.5, 0, 1)
    return np.where(stats.mask, 0.5 * (actions + 1) * (stats.high - stats.low) + stats.low, actions)


def env_actions(normalized: np.ndarray, stats: ActionStatistics, chunk_length: int) -> np.ndarray:
    """The LIBERO actions (chunk_length, 7) of a normalized chunk, as upstream's loop hands them to ``env.step``:
    un-normalized, every value cast to float32, the gripper LIBERO's sign of the float32 value (``> 0.5``: -1).
    Returned as float64 holding those float32 values exactly (``env.step(delta_action.tolist())`` upstream)."""
    if normalized.ndim != 2 or normalized.shape[1] != 7 or len(normalized) < chunk_length:
        raise ValueError(f"normalized_actions row has shape {normalized.shape}, expected at least ({chunk_length}, 7)")
    # Only the rows executed: upstream un-normalizes the whole reply, but every step is row by row (the same bits).
    actions = unnormalize(normalized[:chunk_length], stats).astype(np.float32)
    actions[:, 6] = np.where(actions[:, 6] > 0.5, np.float32(-1.0), np.float32(1.0))
    return actions.astype(np.float64)
