"""The stand-in model behind ``univla_standin_server.py``: numpy only, so tests import it to compute expectations."""

from __future__ import annotations

import numpy as np

WINDOW = 12
ACTION = {"q01": [-0.6, -0.7, -0.8, -0.1, -0.2, -0.3, 0.0], "q99": [0.7, 0.6, 0.9, 0.12, 0.2, 0.3, 1.0],
          "mask": [True] * 6 + [False]}  # fmt: skip
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
STATISTICS = {s: {**ACTION, "q01": [v - 0.02 * i for v in ACTION["q01"]]} for i, s in enumerate(SUITES)}


def prompt_of(instruction: str, history: str) -> str:
    if history:
        return f"In: What action should the robot take to {instruction.lower()}? History action {history}\nOut:"
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


def latent_tokens(prompt: str, seed: int) -> np.ndarray:
    """Four ids among <ACT_0..15> (32001 + k), following the prompt and the request's seed."""
    return np.array([32001 + (len(prompt) * (i + 1) + seed // 7 + i) % 16 for i in range(4)], dtype=np.int64)


def chunk_for(image: np.ndarray, prompt: str, seed: int) -> np.ndarray:
    """(WINDOW, 7) normalized actions: columns follow the image's orientation and crop, the prompt (its history
    included) and the seed; rows change with the step; the gripper alternates below and above 0.5 by prompt."""
    pixels = image.astype(np.float64) / 255.0
    features = np.array([
        pixels[:112].mean() - pixels[112:].mean(),
        pixels[:, :112].mean() - pixels[:, 112:].mean(),
        pixels[20:-20, 20:-20].mean() - pixels.mean(),
        (len(prompt) % 23) / 23.0 - 0.5,
        (seed % 1000) / 1000.0 - 0.5,
        prompt.count("<ACT_") / 8.0,
    ])  # fmt: skip
    gripper = 0.9 if len(prompt) % 2 else 0.2
    return np.array([np.append(np.tanh(features * (1 + 0.05 * t)), gripper) for t in range(WINDOW)])
