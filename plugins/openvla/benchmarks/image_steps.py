"""Cost of the OpenVLA family's client image steps, restated without TensorFlow, beside a naive Pillow pipeline.

    .venv/bin/python plugins/openvla/benchmarks/image_steps.py [--rounds 5]

Times each step on the golden LIBERO renders (``tests/golden/inputs.npz``), interleaved rounds, median per image,
in one process; prints milliseconds and the ratio to the naive pipeline (Pillow's JPEG round trip, LANCZOS resize
and box-bilinear crop, which is not byte-exact: up to 17 levels off). Where TensorFlow is importable it is timed
too (upstream's own ops).
"""

from __future__ import annotations

import argparse
import io
import statistics
import time
from pathlib import Path

import numpy as np
from PIL import Image

from conflictbench.hosting import openvla_family as images

GOLDEN = Path(__file__).resolve().parents[1] / "tests" / "golden" / "inputs.npz"


def naive(rendered: np.ndarray) -> np.ndarray:
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rendered[::-1, ::-1])).save(buffer, format="JPEG", quality=95)
    resized = Image.open(buffer).convert("RGB").resize((224, 224), Image.LANCZOS)
    side = 224 * 0.9**0.5
    offset = (224 - side) / 2
    return np.asarray(resized.resize((224, 224), Image.BILINEAR, box=(offset, offset, offset + side, offset + side)))


def steps() -> dict:
    found = {
        "jpeg round trip": lambda img: images.jpeg_round_trip(img),
        "lanczos resize": lambda img: images.lanczos_resize(img),
        "centre crop": lambda img: images.center_crop(img[:224, :224]),
        "whole client (exact)": lambda img: images.policy_image(img, crop=True),
        "naive Pillow (not exact)": naive,
    }
    try:
        import tensorflow as tf

        def with_tf(img):
            decoded = tf.io.decode_image(tf.image.encode_jpeg(img[::-1, ::-1]), expand_animations=False)
            resized = tf.image.resize(decoded, (224, 224), method="lanczos3", antialias=True)
            return tf.cast(tf.clip_by_value(tf.round(resized), 0, 255), tf.uint8).numpy()

        found["TensorFlow resize_image (upstream)"] = with_tf
    except ImportError:
        pass
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    renders = np.load(GOLDEN)["inputs"][:4]
    timed = steps()
    samples: dict[str, list[float]] = {name: [] for name in timed}
    for _ in range(args.rounds):
        for name, step in timed.items():
            for image in renders:
                started = time.perf_counter()
                step(image)
                samples[name].append((time.perf_counter() - started) * 1000)
    base = statistics.median(samples["naive Pillow (not exact)"])
    for name, values in samples.items():
        median = statistics.median(values)
        print(f"{name:36s} {median:7.2f} ms   {median / base:5.2f} x naive")


if __name__ == "__main__":
    main()
