"""The OpenVLA family's LIBERO client steps: what the clients of OpenVLA, OpenVLA-OFT and UniVLA (whose evaluation
code forks OpenVLA's) do to every image and action, shared by conflictbench-openvla and conflictbench-univla.

The action steps (the facts: ``experiments/robot/robot_utils.py`` of each; ``docs/upstream/openvla_oft_univla.md``):
the gripper mapping (:func:`env_gripper`), the statistics key per suite (:func:`unnorm_key`) and q01/q99
un-normalization (:func:`unnormalize`, in float64: upstream's arithmetic for float64 input, not for OFT's float32
heads; see its docstring), pinned by the plugins' ``test_*_processing.py``.

The image steps, restated exactly without TensorFlow. Upstream's clients (``experiments/robot/libero/libero_utils.py``
and ``openvla_utils.py`` of openvla/openvla, moojink/openvla-oft and OpenDriveLab/UniVLA) run these TensorFlow ops
on every camera image:

1. ``img[::-1, ::-1]``: LIBERO renders upside down;
2. ``tf.image.encode_jpeg`` (quality 95, 4:2:0) then ``tf.io.decode_image``: a JPEG round trip, decoded with
   libjpeg-turbo's fast integer IDCT (JDCT_IFAST) and fancy upsampling;
3. ``tf.image.resize(..., (224, 224), method="lanczos3", antialias=True)``, ``tf.round`` (half to even), clip,
   uint8;
4. the centre crop, where the client or server applies it: ``convert_image_dtype`` to float32 (x / 255),
   ``tf.image.crop_and_resize`` (bilinear) of the centred box of side sqrt(0.9) back to 224 x 224, clip to
   [0, 1], ``convert_image_dtype`` to uint8 with ``saturate=True`` (x * 255.5, truncated).

TensorFlow itself is no dependency: 1.3 GB, 2.5 s to import, and TF >= 2.19 crashes with MuJoCo's EGL
rendering in one process (``docs/upstream/openvla_image_pipeline.md``). Each step below gives TensorFlow's
bytes exactly; ``plugins/openvla/tests/test_openvla_images.py`` compares with outputs TensorFlow made (its
``tests/golden``).
The JPEG encoder is Pillow's libjpeg-turbo (the same entropy-coded data as TF's); the decoder is simplejpeg's
libjpeg-turbo with ``fastdct=True`` (Pillow and OpenCV only decode with the slower exact IDCT, which differs by
up to 19 levels). The resize and crop are float32 numpy restatements of TF's CPU kernels; the Lanczos kernel
calls the C library's ``sinf``, as TF's does (numpy's float32 ``sin`` differs in the last bits of some weights).

Needs the ``openvla-family`` extra, ``conflictbench[openvla-family]``: Pillow and simplejpeg (the plugins of the
family require it; without it, importing this module says so in one line).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import io
from collections.abc import Collection

import numpy as np

from .transport import extra_missing

try:
    import simplejpeg
    from PIL import Image
except ModuleNotFoundError as missing:
    raise extra_missing(__name__, "openvla-family", missing) from None

IMAGE_SIZE = 224
JPEG_QUALITY = 95
CROP_AREA = 0.9
#: ``model.unnorm_key`` values that name the episode's LIBERO suite rather than a literal key.
SUITE_KEYS = {"suite": "{suite}", "suite_no_noops": "{suite}_no_noops"}

_F = np.float32


def upright(rendered: np.ndarray) -> np.ndarray:
    """A LIBERO render turned 180 degrees, as every client of this family does first."""
    return np.ascontiguousarray(rendered[::-1, ::-1])


def jpeg_round_trip(image: np.ndarray) -> np.ndarray:
    """``tf.io.decode_image(tf.image.encode_jpeg(image))``: quality 95, 4:2:0, decoded with the fast IDCT."""
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="JPEG", quality=JPEG_QUALITY, subsampling=2)
    return simplejpeg.decode_jpeg(buffer.getvalue(), colorspace="RGB", fastdct=True, fastupsample=False)


def _sinf_from_libm():
    name = ctypes.util.find_library("m")
    library = ctypes.CDLL(name) if name else ctypes.CDLL(None)
    sinf = library.sinf
    sinf.restype, sinf.argtypes = ctypes.c_float, [ctypes.c_float]
    return sinf


_sinf = _sinf_from_libm()


def _lanczos3(x: np.float32) -> np.float32:
    """TF's ``LanczosKernelFunc`` with radius 3, in float32 (``3 sin(pi x) sin(pi x / 3) / (pi^2 x^2)``)."""
    pi, radius = _F(3.14159265359), _F(3.0)
    x = abs(x)
    if x > radius:
        return _F(0.0)
    if x <= _F(1e-3):
        return _F(1.0)
    value = radius * _F(_sinf(pi * x))
    value = value * _F(_sinf(pi * x / radius))
    return value / (pi * pi * x * x)


@functools.lru_cache(maxsize=8)
def lanczos_weights(in_size: int, out_size: int) -> tuple[np.ndarray, np.ndarray]:
    """TF's ``ComputeSpans`` for an antialiased lanczos3 resize: the first source index of each output and
    the (out_size, span) float32 weights, zero past each output's own span."""
    scale = _F(out_size) / _F(in_size)
    inv_scale = _F(1.0 / scale)
    kernel_scale = max(inv_scale, _F(1.0))
    one_over_kernel_scale = _F(1.0) / kernel_scale
    span = min(2 * int(np.ceil(_F(3.0) * kernel_scale)) + 1, in_size)
    starts = np.zeros(out_size, dtype=np.int64)
    weights = np.zeros((out_size, span), dtype=_F)
    for x in range(out_size):
        sample = _F(x + 0.5) * inv_scale
        start = int(np.ceil(sample - _F(3.0) * kernel_scale - _F(0.5)))
        end = int(np.floor(sample + _F(3.0) * kernel_scale - _F(0.5)))
        start, end = min(max(start, 0), in_size - 1), min(max(end, 0), in_size - 1) + 1
        row = [_lanczos3((_F(source) + _F(0.5) - sample) * one_over_kernel_scale) for source in range(start, end)]
        total = _F(0.0)
        for weight in row:
            total = _F(total + weight)
        if abs(total) >= _F(1000.0) * np.finfo(_F).tiny:
            inverse = _F(1.0) / total
            row = [_F(weight * inverse) for weight in row]
        starts[x], weights[x, : len(row)] = start, row
    return starts, weights


def _gather(image: np.ndarray, starts: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    """One pass of TF's ``GatherRows``/``GatherColumns``: float32 sums in span order along ``axis``."""
    source = np.moveaxis(image, axis, 0)
    limit = source.shape[0]
    out = np.zeros((len(starts), *source.shape[1:]), dtype=_F)
    for k in range(weights.shape[1]):
        index = np.minimum(starts + k, limit - 1)  # past the image the weight is 0: adds exactly nothing
        weight = weights[:, k].reshape((-1,) + (1,) * (source.ndim - 1))
        out = out + weight * source[index]
    return np.moveaxis(out, 0, axis)


def lanczos_resize(image: np.ndarray, size: int = IMAGE_SIZE) -> np.ndarray:
    """``tf.image.resize(image, (size, size), "lanczos3", antialias=True)`` rounded half to even, uint8."""
    height, width = image.shape[:2]
    pixels = image.astype(_F)
    rows = _gather(pixels, *lanczos_weights(height, size), axis=0)  # TF: vertical pass first
    both = _gather(rows, *lanczos_weights(width, size), axis=1)
    return np.clip(np.round(both), 0, 255).astype(np.uint8)


def resize_for_policy(rendered_upright: np.ndarray, size: int = IMAGE_SIZE) -> np.ndarray:
    """Upstream's ``resize_image`` / ``resize_image_for_policy``: JPEG round trip, then the Lanczos resize."""
    return lanczos_resize(jpeg_round_trip(rendered_upright), size)


def center_crop(image: np.ndarray, area: float = CROP_AREA, size: int = IMAGE_SIZE) -> np.ndarray:
    """Upstream's centre crop: the centred box of side sqrt(area), bilinear back to size x size, uint8."""
    height, width = image.shape[:2]
    pixels = image.astype(_F) * _F(1.0 / 255)
    side = min(max(np.sqrt(_F(area)), _F(0.0)), _F(1.0))
    low = (_F(1.0) - side) / _F(2.0)
    high = low + side
    rows = _sample_positions(low, high, height, size)
    cols = _sample_positions(low, high, width, size)
    top, bottom, y_lerp = rows
    left, right, x_lerp = cols
    x_lerp = x_lerp[None, :, None]
    upper = pixels[top][:, left] + (pixels[top][:, right] - pixels[top][:, left]) * x_lerp
    lower = pixels[bottom][:, left] + (pixels[bottom][:, right] - pixels[bottom][:, left]) * x_lerp
    crop = upper + (lower - upper) * y_lerp[:, None, None]
    scaled = np.clip(crop, _F(0.0), _F(1.0)) * _F(255.5)
    return np.clip(scaled, 0, 255).astype(np.uint8)  # astype truncates, as TF's saturate_cast


def _sample_positions(low: np.float32, high: np.float32, in_size: int, out_size: int):
    """``crop_and_resize``'s source positions along one axis: floor and ceil indices and the lerp weight."""
    step = (high - low) * _F(in_size - 1) / _F(out_size - 1)
    positions = np.array([low * _F(in_size - 1) + _F(i) * step for i in range(out_size)], dtype=_F)
    floor = np.floor(positions).astype(np.int64)
    return floor, np.ceil(positions).astype(np.int64), (positions - floor.astype(_F)).astype(_F)


def policy_image(rendered: np.ndarray, crop: bool) -> np.ndarray:
    """One LIBERO render as this family's client hands it on: upright, JPEG, Lanczos to 224, then (where
    the client crops) the centre crop."""
    resized = resize_for_policy(upright(rendered))
    return center_crop(resized) if crop else resized


def env_gripper(actions: np.ndarray) -> np.ndarray:
    """``normalize_gripper_action(binarize=True)`` then ``invert_gripper_action``, on a copy: the last
    dimension g in [0, 1] (1 = open) becomes ``-sign(2 g - 1)`` (LIBERO's -1 = open; g = 0.5 exactly gives 0)."""
    out = np.array(actions, dtype=np.float64)
    out[..., -1] = -np.sign(2.0 * out[..., -1] - 1.0)
    return out


def unnorm_key(setting: str, suite: str, known: Collection[str] | None = None) -> str:
    """The statistics key for an episode of ``suite``: ``suite`` / ``suite_no_noops`` follow the suite; any
    other setting is the key itself. Where the checkpoint's keys are ``known``, ``suite`` falls back to the
    ``_no_noops`` key when only that one exists, as upstream's evaluations do."""
    template = SUITE_KEYS.get(setting)
    if template is None:
        return setting
    if not suite:
        raise ValueError(f"unnorm_key={setting} needs the episode's LIBERO suite, and the observation has none")
    key = template.format(suite=suite)
    if known is not None and key not in known and f"{key}_no_noops" in known and setting == "suite":
        return f"{key}_no_noops"
    return key


def unnormalize(normalized: np.ndarray, stats: dict, epsilon: float = 0.0) -> np.ndarray:
    """q01/q99 un-normalization where ``stats["mask"]`` keeps the dimension (all where it has no mask).

    The input is widened to float64 first, so every step is float64. That is upstream's arithmetic for float64
    input: OpenVLA's and OFT's bin centres, UniVLA's ensembled actions (its loop un-normalizes float64 too). It is
    not OFT's for its L1 and diffusion heads, whose float32 output upstream's model code un-normalizes with
    ``0.5 * (a + 1)`` in float32 (moojink/openvla-oft@213c5ff ``prismatic/extern/hf/modeling_prismatic.py:787``,
    output dtype ``:875``, ``:925``): on float32 uniform in [-1.05, 1.05], 2849 of 7000 values differ, by up to
    1.1e-7 (``docs/upstream/audit_openvla.md``). No run takes that path: our server refuses OFT checkpoints, and
    against OFT's ``deploy.py`` the un-normalization runs there. ``epsilon`` is OFT's ``+ 1e-8``.
    """
    low, high = np.asarray(stats["q01"], dtype=np.float64), np.asarray(stats["q99"], dtype=np.float64)
    mask = np.asarray(stats.get("mask", np.ones_like(low, dtype=bool)), dtype=bool)
    normalized = np.asarray(normalized, dtype=np.float64)
    return np.where(mask, 0.5 * (normalized + 1.0) * (high - low + epsilon) + low, normalized)
