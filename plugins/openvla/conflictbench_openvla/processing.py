"""What the OpenVLA family's LIBERO clients and models do around the network, step by step.

The client steps OpenVLA, OFT and UniVLA share (the gripper, the statistics key, q01/q99 un-normalization; their
names stay importable here) live in :mod:`conflictbench.hosting.openvla_family`; this module keeps the rest (it
runs in the model environment too, where there is no conflictbench). Pinned by ``tests/test_openvla_processing.py``.
The facts, from ``experiments/robot/libero/run_libero_eval.py``, ``robot_utils.py`` and ``openvla_utils.py`` of
openvla/openvla, moojink/openvla-oft and OpenDriveLab/UniVLA, and the models' ``modeling_prismatic.py``
(``docs/upstream/openvla_oft_univla.md`` has the lines):

- **gripper**: the model's g in [0, 1] (1 = open) becomes ``2 g - 1``, then its sign, then is negated (LIBERO's
  -1 = open); ``np.sign(0) = 0``, so g = 0.5 exactly leaves the gripper command at 0;
- **unnorm_key**: the LIBERO suite's name (``libero_goal``), or its ``_no_noops`` variant where the checkpoint
  has only that one (trained on the no-op-filtered datasets);
- **de-tokenization** (OpenVLA, in the model): 256 bins in [-1, 1] have 255 centres; the action token ``id``
  is bin ``vocab_size - id - 1`` clipped to [0, 254];
- **q01/q99 un-normalization**: ``0.5 (a + 1)(q99 - q01) + q01`` on the dimensions the statistics' ``mask``
  keeps (LIBERO's excludes the gripper, which stays a bin centre); OpenVLA-OFT adds 1e-8 to ``q99 - q01``.
  ``openvla_family.unnormalize`` computes it in float64, widening its input first: OpenVLA's arithmetic (float64
  bin centres), not OFT's for the float32 output of its L1 and diffusion heads (``0.5 (a + 1)`` in float32 there);
  no run takes that path (OFT's un-normalization runs in OFT's ``deploy.py``), see ``docs/upstream/audit_openvla.md``;
- **OFT's proprio**: ``2 (x - q01) / (q99 - q01 + 1e-8) - 1`` clipped to [-1, 1];
- **steps**: 220 / 280 / 300 / 520 policy steps for libero_spatial / object / goal / 10 (OpenVLA and OFT), after
  10 no-op warm-up steps.
"""

from __future__ import annotations

import numpy as np

MAX_STEPS = {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
ACTION_BINS = 256
OFT_EPSILON = 1e-8


def prompt(instruction: str) -> str:
    """The prompt OpenVLA's ``deploy.py`` and the OFT / UniVLA models build from the task text."""
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


def bin_centers(bins: int = ACTION_BINS) -> np.ndarray:
    """The ``bins - 1`` centres of ``bins`` uniform bins over [-1, 1] (float64, as the model's)."""
    edges = np.linspace(-1.0, 1.0, bins)
    return (edges[:-1] + edges[1:]) / 2.0


def detokenize(token_ids: np.ndarray, vocab_size: int, bins: int = ACTION_BINS) -> np.ndarray:
    """OpenVLA's normalized actions for generated action tokens: centre ``clip(vocab_size - id - 1, 0, bins - 2)``."""
    index = np.clip(vocab_size - np.asarray(token_ids, dtype=np.int64) - 1, 0, bins - 2)
    return bin_centers(bins)[index]


def normalize_proprio(state: np.ndarray, stats: dict) -> np.ndarray:
    """OpenVLA-OFT's proprio normalization (BOUNDS_Q99): to [-1, 1] with q01/q99 where the mask keeps, clipped."""
    low, high = np.asarray(stats["q01"], dtype=np.float64), np.asarray(stats["q99"], dtype=np.float64)
    mask = np.asarray(stats.get("mask", np.ones_like(low, dtype=bool)), dtype=bool)
    state = np.asarray(state, dtype=np.float64)
    normalized = np.where(mask, 2.0 * (state - low) / (high - low + OFT_EPSILON) - 1.0, state)
    return np.clip(normalized, -1.0, 1.0)


_MOVED = ("SUITE_KEYS", "env_gripper", "unnorm_key", "unnormalize")


def __getattr__(name: str):
    """Names that moved to the client layer in 0.3 (deprecated, they go in 0.4.0): imported on use, since the model
    environment, which runs this module too, has no conflictbench."""
    if name not in _MOVED:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from conflictbench.core.deprecation import moved_names

    moved = moved_names(__name__, {name: f"conflictbench.hosting.openvla_family:{name}"})
    return moved(name, 2)  # the warning blames the code that read the name, past this function
