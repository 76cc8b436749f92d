"""Write ``tf_images.npz``: what TensorFlow's ops make of a few images, as the OpenVLA family's clients call them.

Run it with a Python that has TensorFlow (``pip install tensorflow-cpu==2.18.1 numpy==1.26.4``; upstream pins
2.15.0, and 2.15 to 2.21 give the same bytes) and with the inputs file this folder holds:

    python make_tf_golden.py inputs.npz tf_images.npz

The inputs are LIBERO renders (agentview and wrist, libero_goal task 5 and libero_10 task 2, initial state 0,
after the 10 warm-up steps, already turned upright) and synthetic images that stress each step (noise, hard
edges, saturation). The ops and their arguments are those of upstream's ``resize_image`` (``libero_utils.py``)
and ``crop_and_resize`` / ``get_vla_action`` (``openvla_utils.py``).
"""

import sys

import numpy as np
import tensorflow as tf


def jpeg(image):
    encoded = tf.image.encode_jpeg(image)
    return tf.io.decode_image(encoded, expand_animations=False, dtype=tf.uint8)


def resize(image, size=224):
    resized = tf.image.resize(jpeg(image), (size, size), method="lanczos3", antialias=True)
    return tf.cast(tf.clip_by_value(tf.round(resized), 0, 255), tf.uint8)


def crop(image, crop_scale=0.9):
    pixels = tf.image.convert_image_dtype(tf.convert_to_tensor(image), tf.float32)[None]
    side = tf.reshape(tf.clip_by_value(tf.sqrt(crop_scale), 0, 1), shape=(1,))
    offset = (1 - side) / 2
    boxes = tf.stack([offset, offset, offset + side, offset + side], axis=1)
    cropped = tf.image.crop_and_resize(pixels, boxes, tf.range(1), (224, 224))[0]
    return tf.image.convert_image_dtype(tf.clip_by_value(cropped, 0, 1), tf.uint8, saturate=True)


def main(inputs_path: str, out_path: str) -> None:
    tf.config.threading.set_intra_op_parallelism_threads(1)
    inputs = np.load(inputs_path)["inputs"]
    jpegs = np.stack([jpeg(image).numpy() for image in inputs])
    resized = np.stack([resize(image).numpy() for image in inputs])
    cropped = np.stack([crop(image).numpy() for image in resized])
    np.savez_compressed(out_path, jpeg=jpegs, resized=resized, cropped=cropped, tensorflow=tf.__version__)


if __name__ == "__main__":
    main(*sys.argv[1:3])
