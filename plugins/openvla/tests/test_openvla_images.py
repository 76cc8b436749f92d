"""The image steps against TensorFlow's own outputs (``golden/tf_images.npz``, made by ``golden/make_tf_golden.py``).

Upstream runs these steps in TensorFlow; ours restate them without it, and must give the same bytes: a
difference of one level in one pixel fails.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conflictbench.hosting import openvla_family as images

GOLDEN = Path(__file__).resolve().parent / "golden"


@pytest.fixture(scope="module")
def golden():
    inputs = np.load(GOLDEN / "inputs.npz")["inputs"]
    made_by_tf = dict(np.load(GOLDEN / "tf_images.npz"))
    assert inputs.shape == (6, 256, 256, 3) and made_by_tf["resized"].shape == (6, 224, 224, 3)
    return inputs, made_by_tf


def differing(ours: np.ndarray, theirs: np.ndarray) -> int:
    assert ours.shape == theirs.shape and ours.dtype == theirs.dtype == np.uint8
    return int(np.count_nonzero(ours != theirs))


def test_jpeg_round_trip_gives_tensorflows_decoded_pixels(golden):
    inputs, tf = golden
    assert [differing(images.jpeg_round_trip(image), tf["jpeg"][i]) for i, image in enumerate(inputs)] == [0] * 6


def test_jpeg_then_lanczos_resize_gives_tensorflows_bytes(golden):
    inputs, tf = golden
    resized = [images.resize_for_policy(image) for image in inputs]
    assert [differing(ours, tf["resized"][i]) for i, ours in enumerate(resized)] == [0] * 6


def test_center_crop_gives_tensorflows_bytes(golden):
    _, tf = golden
    assert [differing(images.center_crop(image), tf["cropped"][i]) for i, image in enumerate(tf["resized"])] == [0] * 6


def test_the_shortcuts_a_port_might_take_are_not_exact(golden):
    """Why the restatement exists: Pillow's own decoder and resize miss TensorFlow's bytes on these images."""
    from PIL import Image

    inputs, tf = golden
    pil_resized = np.asarray(Image.fromarray(inputs[0]).resize((224, 224), Image.LANCZOS))
    assert differing(pil_resized, tf["resized"][0]) > 1000
    slow_idct = np.asarray(Image.open(_jpeg_file(inputs[0])).convert("RGB"))
    assert differing(slow_idct, tf["jpeg"][0]) > 1000


def _jpeg_file(image: np.ndarray):
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG", quality=95)
    buffer.seek(0)
    return buffer


def test_the_policy_image_is_upright_resized_and_cropped_only_where_asked(golden):
    inputs, tf = golden
    rendered = np.ascontiguousarray(inputs[0][::-1, ::-1])  # as LIBERO renders it: upside down
    assert differing(images.policy_image(rendered, crop=False), tf["resized"][0]) == 0
    assert differing(images.policy_image(rendered, crop=True), tf["cropped"][0]) == 0


def test_lanczos_weights_cover_each_output_once():
    starts, weights = images.lanczos_weights(256, 224)
    assert weights.dtype == np.float32 and weights.shape == (224, 9)  # 2 ceil(3 x 256/224) + 1
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-6)
    assert starts[0] == 0 and starts[-1] + np.count_nonzero(weights[-1]) == 256
    assert np.all(np.diff(starts) >= 0)


def test_tensorflow_agrees_where_it_is_installed(golden):
    """On a machine with TensorFlow (< 2.19 beside MuJoCo's EGL), also compare with it live, on new images."""
    tf = pytest.importorskip("tensorflow", reason="TensorFlow is not installed (the golden files stand in for it)")
    rng = np.random.default_rng(11)
    for _ in range(3):
        image = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)
        decoded = tf.io.decode_image(tf.image.encode_jpeg(image), expand_animations=False, dtype=tf.uint8)
        resized = tf.image.resize(decoded, (224, 224), method="lanczos3", antialias=True)
        theirs = tf.cast(tf.clip_by_value(tf.round(resized), 0, 255), tf.uint8).numpy()
        assert differing(images.resize_for_policy(image), theirs) == 0
