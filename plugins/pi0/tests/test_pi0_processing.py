"""Golden tests of openpi's LIBERO client processing, each against openpi's own code or the upstream facts."""

from __future__ import annotations

import numpy as np
import pytest
from openpi_client import image_tools

from conflictbench.core import DEFAULT_MAX_STEPS, PolicyTraits
from conflictbench_pi0.client import PiConfig, PiPolicy
from conflictbench_pi0.processing import IMAGE_SIZE, REPLAN_STEPS, camera_image, resize_with_pad, rotate_180


def random_image(height: int, width: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


@pytest.mark.parametrize("shape", [(256, 256), (480, 640), (640, 480), (100, 300), (224, 224), (37, 51)])
def test_letterboxing_matches_openpi_clients_own_resize_with_pad(shape):
    image = random_image(*shape)
    ours = resize_with_pad(image, 224, 224)
    theirs = image_tools.resize_with_pad(image, 224, 224)
    assert ours.shape == (224, 224, 3) and ours.dtype == np.uint8
    np.testing.assert_array_equal(ours, theirs)


def test_a_wide_image_is_centred_between_black_bars():
    image = np.full((100, 200, 3), 200, dtype=np.uint8)
    out = resize_with_pad(image, 224, 224)
    rows = np.flatnonzero(out[:, 112, 0])  # scaled to 224 x 112, centred vertically: 56 black rows above
    assert (rows[0], rows[-1]) == (56, 56 + 112 - 1)
    assert out[:56].max() == 0 and out[56 + 112 :].max() == 0


def test_camera_images_are_turned_upright_before_letterboxing():
    image = random_image(256, 256, seed=3)
    image[0, 0] = (255, 0, 0)  # LIBERO's first pixel is the bottom-right one of the upright view
    upright = rotate_180(image)
    assert tuple(upright[-1, -1]) == (255, 0, 0)
    np.testing.assert_array_equal(upright, np.rot90(image, 2))
    np.testing.assert_array_equal(camera_image(image), image_tools.resize_with_pad(image[::-1, ::-1], 224, 224))
    assert camera_image(image).shape == (IMAGE_SIZE, IMAGE_SIZE, 3)


def test_openpi_clients_constants():
    # examples/libero/main.py: resize_size 224, replan_steps 5, num_steps_wait 10, and its max steps
    assert (IMAGE_SIZE, REPLAN_STEPS) == (224, 5)
    assert PiConfig().replan_steps == 5
    traits = PolicyTraits(PiPolicy)  # class-level declarations; the 256-px render openpi's env uses
    assert traits.warmup_steps == 10 and traits.image_size == 256 and traits.needs_images
    assert traits.max_steps == dict(DEFAULT_MAX_STEPS)
    assert traits.max_steps == {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520}


@pytest.mark.parametrize(
    "names, expected",
    [
        (
            ["observation.images.image", "observation.images.image2"],
            ["observation.images.image", "observation.images.image2"],
        ),
        (
            ["observation.images.image2", "observation.images.image"],
            ["observation.images.image", "observation.images.image2"],
        ),
        (
            ["observation.images.wrist_image", "observation.images.agentview"],
            ["observation.images.agentview", "observation.images.wrist_image"],
        ),
        (
            ["observation.images.cam_a", "observation.images.cam_b"],
            ["observation.images.cam_a", "observation.images.cam_b"],
        ),
    ],
)
def test_the_wrist_image_goes_to_the_checkpoints_wrist_camera_whatever_its_order(names, expected):
    from conflictbench_pi0.backend import camera_order  # importable without torch: it loads lazily

    assert camera_order(names) == expected
