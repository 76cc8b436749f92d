"""The observations the UniVLA arithmetic test (``test_univla_upstream_arithmetic.py``) feeds our client and the
restatement of upstream's loop alike: numpy only, so ``golden/make_upstream_images.py`` builds the same ones under a
Python with TensorFlow (which upstream's image steps need and this project's environment does not have).

- ``golden/libero_observation.npz``: one real LIBERO observation as UniVLA's loop gets it for its first query
  (``libero_goal`` task 0, initial state 0, a 256-px ``OffScreenRenderEnv``, ``env.seed(0)``, 10 no-op steps), the
  agentview render as LIBERO gives it (upside down) and the robot state;
- :func:`synthetic_renders`: 256-px renders with what a LIBERO scene has (smooth shaded table and wall, objects with
  hard edges, saturated highlights and shadows, sensor-like noise), upside down as LIBERO's, seeded.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

GOLDEN = Path(__file__).resolve().parent / "golden"
REAL_OBSERVATION = GOLDEN / "libero_observation.npz"
#: What golden/make_upstream_images.py wrote: upstream's ``request`` images for :func:`observations`.
UPSTREAM_IMAGES = GOLDEN / "upstream_images.npz"
SYNTHETIC = 3


def synthetic_renders(count: int = SYNTHETIC, size: int = 256) -> list[np.ndarray]:
    """``count`` renders (uint8 size x size x 3), the same every time."""
    renders = []
    for seed in range(count):
        rng = np.random.default_rng(seed)
        y, x = np.mgrid[0:size, 0:size].astype(np.float64) / size
        wall = y < rng.uniform(0.3, 0.45)
        image = np.where(
            wall[..., None],
            np.stack([0.75 - 0.2 * y, 0.72 - 0.1 * x, 0.68 + 0.05 * x], -1),
            np.stack([0.55 + 0.25 * y, 0.4 + 0.2 * y * x, 0.25 + 0.1 * x], -1),
        )
        for _ in range(7):
            cy, cx = rng.uniform(0.15, 0.9, 2)
            ry, rx = rng.uniform(0.03, 0.14, 2)
            colour = rng.uniform(0.0, 1.0, 3)
            if rng.random() < 0.5:
                inside = ((y - cy) / ry) ** 2 + ((x - cx) / rx) ** 2 <= 1.0
            else:
                inside = (abs(y - cy) <= ry) & (abs(x - cx) <= rx)
            shade = 1.15 - 0.5 * np.clip((y - cy) / ry + 1.0, 0.0, 2.0) / 2.0  # lit from above
            image[inside] = colour * shade[inside][:, None]
        image[8:24, 200:240] = 1.0  # a highlight, saturated
        image[230:250, 10:60] = 0.0  # a shadow, black
        pixels = np.clip(np.round(image * 255.0 + rng.normal(0.0, 1.0, image.shape)), 0, 255).astype(np.uint8)
        renders.append(np.ascontiguousarray(pixels[::-1, ::-1]))  # LIBERO renders upside down
    return renders


def observations() -> list[dict]:
    """LIBERO observation dicts (``OffScreenRenderEnv``'s keys): the real one first, then the synthetic ones with
    the real one's robot state."""
    real = dict(np.load(REAL_OBSERVATION))
    state = {key: real[key] for key in ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos")}
    return [real] + [{"agentview_image": render, **state} for render in synthetic_renders()]
