"""The stand-in model behind ``deploy_standin_server.py``: numpy only, so tests import it to compute expectations."""

from __future__ import annotations

import numpy as np

#: LIBERO-like statistics, as a checkpoint's ``dataset_statistics.json`` holds them (the gripper masked out).
ACTION = {"q01": [-0.7, -0.8, -0.9, -0.1, -0.2, -0.3, 0.0], "q99": [0.8, 0.7, 0.9, 0.12, 0.2, 0.35, 1.0],
          "mask": [True] * 6 + [False]}  # fmt: skip
PROPRIO = {"q01": [-0.2, -0.3, 0.8, 2.9, -0.5, -0.4, 0.0, -0.04], "q99": [0.2, 0.3, 1.2, 3.3, 0.5, 0.4, 0.04, 0.0]}
STATS = {
    key: {"action": {**ACTION, "q01": [v + 0.01 * i for v in ACTION["q01"]]}, "proprio": PROPRIO}
    for i, key in enumerate(["libero_spatial", "libero_object", "libero_goal", "libero_10", "libero_goal_no_noops"])
}
CHUNK = 8


def prompt_of(instruction: str) -> str:
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


def normalized_for(images: list[np.ndarray], prompt: str, proprio: np.ndarray | None) -> np.ndarray:
    """(8, 7) normalized actions: columns follow the images' orientation and crop, the prompt and the proprio;
    rows grow with the step; the gripper is 0.9 (open), 0.2 (closed) or, for a prompt holding "halfway", 0.5."""
    image = images[0].astype(np.float64) / 255.0
    wrist = images[1].astype(np.float64) / 255.0 if len(images) > 1 else image
    features = np.array([
        image[:112].mean() - image[112:].mean(),  # which way up
        image[:, :112].mean() - image[:, 112:].mean(),  # which way round
        image[20:-20, 20:-20].mean() - image.mean(),  # how far in the crop reaches
        (len(prompt) % 17) / 17.0 - 0.5,
        wrist[:112].mean() - wrist[112:].mean(),
        float(np.tanh(proprio.sum())) if proprio is not None else 0.0,
    ])  # fmt: skip
    gripper = 0.5 if "halfway" in prompt else (0.9 if len(prompt) % 2 else 0.2)
    rows = [np.append(np.clip(features * (1 + 0.1 * t), -1, 1), gripper) for t in range(CHUNK)]
    return np.array(rows)


def unnormalized(normalized: np.ndarray, stats: dict, epsilon: float) -> np.ndarray:
    low, high, mask = (np.asarray(stats[k], dtype=np.float64) for k in ("q01", "q99", "mask"))
    return np.where(mask.astype(bool), 0.5 * (normalized + 1) * (high - low + epsilon) + low, normalized)
