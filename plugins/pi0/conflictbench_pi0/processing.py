"""What openpi's LIBERO client does around the model (``examples/libero/main.py``), step by step.

The facts (each pinned by a test in ``tests/test_pi0_processing.py``):

- both camera images are rotated 180 degrees (LIBERO renders them upside down), then letterboxed to
  224 x 224 (``resize_with_pad``: scale to fit, bilinear, centre on black), as uint8;
- the state is LIBERO's 8-D vector: end-effector position, the axis-angle of its quaternion, the two
  gripper joint positions (the simulator records it as ``Observation.state``);
- the prompt is the task text as it is (here: after P0/P1 formatting);
- the server's chunk is already in the environment's units and gripper convention; the first 5 actions
  are executed, then the client asks again (``replan_steps``);
- 10 no-op warm-up steps, and 220 / 280 / 300 / 520 policy steps at most per LIBERO suite (conflictbench's
  defaults, the same as openpi's).

The server side (normalizing the state, un-normalizing the actions) is the model's policy transforms, on
the server: nothing here repeats it.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

#: Side of the square images openpi's LIBERO client sends.
IMAGE_SIZE = 224
#: Actions of each returned chunk executed before asking again.
REPLAN_STEPS = 5


def rotate_180(image: np.ndarray) -> np.ndarray:
    """LIBERO's upside-down render turned the right way up (rows and columns reversed)."""
    return np.ascontiguousarray(image[::-1, ::-1])


def resize_with_pad(image: np.ndarray, height: int = IMAGE_SIZE, width: int = IMAGE_SIZE) -> np.ndarray:
    """``image`` (H, W, 3) uint8 scaled to fit ``height`` x ``width`` without distortion, centred on black.

    The scaled size rounds down and the offsets are the floor of half the margin (TensorFlow's
    ``resize_with_pad`` as openpi's client reproduces it with PIL's bilinear filter). An image already
    of the target size is returned unchanged.
    """
    if image.dtype != np.uint8 or image.ndim != 3:
        raise ValueError(f"expected an (H, W, C) uint8 image, got {image.dtype} {image.shape}")
    in_height, in_width = image.shape[:2]
    if (in_height, in_width) == (height, width):
        return image
    scale = max(in_width / width, in_height / height)
    new_width, new_height = int(in_width / scale), int(in_height / scale)
    scaled = np.asarray(Image.fromarray(image).resize((new_width, new_height), resample=Image.BILINEAR))
    top, left = max(0, int((height - new_height) / 2)), max(0, int((width - new_width) / 2))
    padded = np.zeros((height, width, image.shape[2]), dtype=np.uint8)
    padded[top : top + new_height, left : left + new_width] = scaled
    return padded


def camera_image(rendered: np.ndarray) -> np.ndarray:
    """One camera as the client sends it: turned upright, letterboxed to 224."""
    return resize_with_pad(rotate_180(rendered))


def executed_part(chunk: np.ndarray, replan_steps: int = REPLAN_STEPS) -> np.ndarray:
    """The actions of a reply executed before the next query: its first ``replan_steps`` rows, values unchanged.

    openpi's client passes each as ``row.tolist()`` (Python floats: each element's exact value) and robosuite reads
    an action through ``np.clip`` / ``np.sign``, as float64; a float64 row is read the same, bit for bit.
    """
    return chunk[:replan_steps]
