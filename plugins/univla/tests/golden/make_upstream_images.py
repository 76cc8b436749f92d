"""Write ``upstream_images.npz``: the images upstream's UniVLA loop hands its processor for the observations of
``univla_upstream_inputs.py``, made by the restatement of upstream (``upstream_univla.request``) with TensorFlow, as
upstream's client makes them (OpenDriveLab/UniVLA pins tensorflow 2.15.0).

Run it with a Python that has TensorFlow, numpy and Pillow (``pip install tensorflow-cpu==2.15.0 numpy==1.26.4
pillow``), from anywhere:

    python plugins/univla/tests/golden/make_upstream_images.py

``full_image`` is ``observation["full_image"]`` (upright, JPEG round trip, Lanczos to 224: no centre crop), ``image``
what reaches the processor with UniVLA's default ``center_crop=True``.
"""

import sys
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

import tensorflow as tf  # noqa: E402
import upstream_univla as upstream  # noqa: E402
from univla_upstream_inputs import UPSTREAM_IMAGES, observations  # noqa: E402


def main() -> None:
    tf.config.threading.set_intra_op_parallelism_threads(1)
    made = [upstream.request(obs, "any task") for obs in observations()]
    np.savez_compressed(
        UPSTREAM_IMAGES,
        full_image=np.stack([request["full_image"] for request in made]),
        image=np.stack([request["image"] for request in made]),
        tensorflow=np.array(tf.__version__),
        source=np.array(f"{upstream.SOURCE['repository']}@{upstream.SOURCE['commit']}"),
    )
    print(f"wrote {UPSTREAM_IMAGES} with TensorFlow {tf.__version__}")


if __name__ == "__main__":
    main()
