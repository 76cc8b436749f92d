"""OpenVLA's LIBERO client, restated from upstream's source by a separate reader (issue #43).

Written from openvla/openvla@c8f03f4 only (no conflictbench code was read). Every step cites
`openvla/openvla@c8f03f4 <file>:<line>`; the step list in prose is docs/upstream/openvla_client_steps.md.

What "upstream's LIBERO client" is here. Upstream's LIBERO eval (`run_libero_eval.py`) runs the model *in process*:
`get_vla_action` does the center crop, the prompt, the processor and `vla.predict_action`. Upstream's REST server
(`vla-scripts/deploy.py`) runs only `Image.fromarray(image).convert("RGB")`, the prompt, the processor and
`predict_action`: it does no center crop. A REST client that reproduces the LIBERO eval therefore does, on its side,
everything `get_vla_action` does before the processor (rotate 180°, JPEG round trip + lanczos3 resize, center crop),
and sends `{"image", "instruction", "unnorm_key"}`, the keys deploy.py reads. That split is this reader's composition
of two upstream files; every step in it is upstream's.

Which side each step runs on:

    client  obs -> rotate 180° -> TF JPEG round trip + TF lanczos3 resize -> [TF center crop] -> payload
    server  Image.fromarray(image).convert("RGB"), prompt (lower-cased), HF processor, predict_action
            (greedy generate, token -> bin center, un-normalize: `unnormalize` below) -> float64 (7,) reply
    client  reply -> normalize_gripper_action(binarize=True) -> invert_gripper_action -> env.step(action.tolist())

TensorFlow steps (JPEG encode/decode, resize, center crop) are TF's own kernels; `tf_resize_image` and
`tf_center_crop` call them exactly as upstream does and import TensorFlow lazily (it is not installed in the test
venv). `request` takes `resize_fn=` / `center_crop_fn=` to substitute them (e.g. with a table of TF's golden output).

`predict_action` (the un-normalization) is model code: the repository's copy
(prismatic/extern/hf/modeling_prismatic.py) is readable and restated in `unnormalize`/`detokenize`; the code that
actually runs for an HF Hub checkpoint (openvla/openvla-7b-finetuned-libero-*) is the checkpoint's own
modeling_prismatic.py behind `trust_remote_code` (deploy.py:77-84), not readable here: unverified.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from PIL import Image

SOURCE = {
    "repository": "openvla/openvla",
    "commit": "c8f03f48af692657d3060c19588038c7220e9af9",
    "files": [
        "experiments/robot/libero/run_libero_eval.py",
        "experiments/robot/libero/libero_utils.py",
        "experiments/robot/robot_utils.py",
        "experiments/robot/openvla_utils.py",
        "vla-scripts/deploy.py",
        "prismatic/extern/hf/modeling_prismatic.py",
        "prismatic/extern/hf/configuration_prismatic.py",
    ],
}

# ---- episode constants -------------------------------------------------------------------------------------------
ENV_RESOLUTION = 256  # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:156 (resolution=256)
ENV_SEED = 0  # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:24 (env.seed(0))
NUM_STEPS_WAIT = 10  # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:72
# dummy action stepped while t < NUM_STEPS_WAIT (a list of ints, passed as is)
DUMMY_ACTION = [0, 0, 0, 0, 0, 0, -1]  # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:28-30
# policy steps per episode; the loop runs while t < MAX_STEPS[suite] + NUM_STEPS_WAIT
# openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:173-182 (bound at :186)
MAX_STEPS = {
    "libero_spatial": 220,
    "libero_object": 280,
    "libero_goal": 300,
    "libero_10": 520,
    "libero_90": 400,
}
NUM_TRIALS_PER_TASK = 50  # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:73
SEED = 7  # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:85 (set_seed_everywhere, :98)
TASK_SUITE_NAME = "libero_spatial"  # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:71
RESIZE_SIZE = 224  # openvla/openvla@c8f03f4 experiments/robot/robot_utils.py:56-57
# README.md:555-580 evaluates with --center_crop True, the default
CENTER_CROP = True  # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:66
CROP_SCALE = 0.9  # openvla/openvla@c8f03f4 experiments/robot/openvla_utils.py:137
ACTION_DIM = 7  # openvla/openvla@c8f03f4 experiments/robot/robot_utils.py:16 (asserted at :69)
SERVER_PORT = 8000  # openvla/openvla@c8f03f4 vla-scripts/deploy.py:133
# Revisions: the LIBERO eval first appears at a793354 (2024-09-04); 7a359de (2024-09-06) added the `_no_noops`
# unnorm_key fallback (run_libero_eval.py:108-111); d9a949f (2024-08-15) fixed deploy.py's `encoded` assert (before
# it, `len(payload.keys() == 1)` raised, so the double-encoded form always answered "error"); d7dbea8 (2024-08-14)
# made predict_action append token 29871 only when missing. Nothing else in these files changed up to c8f03f4.


# ---- in: observation -> payload (client side) ---------------------------------------------------------------------
def quat2axisangle(quat: np.ndarray) -> np.ndarray:
    """xyzw quaternion -> axis-angle, upstream's arithmetic in its order (float64 for LIBERO's float64 quat).

    Upstream clips `quat[3]` in place (it mutates obs["robot0_eef_quat"]); this copy clips a copy, same values.
    """
    quat = np.array(quat, copy=True)
    # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:91-94: clip w to [-1, 1]
    if quat[3] > 1.0:
        quat[3] = 1.0
    elif quat[3] < -1.0:
        quat[3] = -1.0
    den = np.sqrt(1.0 - quat[3] * quat[3])  # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:96
    # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:97-99: math.isclose with default tolerances
    # (rel_tol=1e-9, abs_tol=0.0) is true only for den == 0.0 exactly; then float64 zeros
    if math.isclose(den, 0.0):
        return np.zeros(3)
    # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:101: ((xyz * 2.0) * acos(w)) / den
    return (quat[:3] * 2.0 * math.acos(quat[3])) / den


def libero_state(obs: dict) -> np.ndarray:
    """The 8-D state upstream builds (float64): eef_pos (3), axis-angle (3), gripper_qpos (2).

    openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:202-208 builds it into `observation["state"]`,
    but OpenVLA never reads it ("OpenVLA does not take proprio state as input"): it is not in the payload.
    """
    return np.concatenate((obs["robot0_eef_pos"], quat2axisangle(obs["robot0_eef_quat"]), obs["robot0_gripper_qpos"]))


def rotate_180(img: np.ndarray) -> np.ndarray:
    """`img[::-1, ::-1]`, a view (numpy). openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:56"""
    return img[::-1, ::-1]


def tf_resize_image(img: np.ndarray, resize_size: tuple[int, int]) -> np.ndarray:
    """TensorFlow's steps, called as upstream calls them (uint8 HxWx3 in, uint8 out).

    openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:33-47 (`resize_image`):
    """
    import tensorflow as tf  # TF's ops; not installed in conflictbench's test venv

    assert isinstance(resize_size, tuple)  # libero_utils.py:40
    # libero_utils.py:42: TF's JPEG encoder with TF's defaults (quality 95, 4:2:0 chroma downsampling)
    data = tf.image.encode_jpeg(img)
    # libero_utils.py:43: TF's decoder (libjpeg-turbo, TF's own decoder settings), uint8
    decoded = tf.io.decode_image(data, expand_animations=False, dtype=tf.uint8)
    # libero_utils.py:44: TF's ScaleAndTranslate lanczos3 with antialias, float32 output
    resized = tf.image.resize(decoded, resize_size, method="lanczos3", antialias=True)
    # libero_utils.py:45: tf.round (half to even), clip to [0, 255], cast to uint8
    out = tf.cast(tf.clip_by_value(tf.round(resized), 0, 255), tf.uint8)
    return out.numpy()  # libero_utils.py:46


def tf_center_crop(img: np.ndarray, crop_scale: float = CROP_SCALE) -> np.ndarray:
    """TensorFlow's center crop as upstream calls it (uint8 224x224x3 in, uint8 224x224x3 out).

    openvla/openvla@c8f03f4 experiments/robot/openvla_utils.py:135-155 (in `get_vla_action`) with `crop_and_resize`
    at :81-124. The output size is the literal (224, 224) of :118, whatever the input size.
    """
    import tensorflow as tf  # TF's ops

    batch_size = 1  # openvla_utils.py:136
    image = tf.convert_to_tensor(img)  # openvla_utils.py:140 (np.array of the PIL RGB image)
    orig_dtype = image.dtype  # openvla_utils.py:141 (tf.uint8)
    image = tf.image.convert_image_dtype(image, tf.float32)  # openvla_utils.py:144: uint8 -> float32 in [0, 1]
    image = tf.expand_dims(image, axis=0)  # openvla_utils.py:96-98 (3-D input gets a batch axis)
    # openvla_utils.py:101-102: side = clip(sqrt(crop_scale), 0, 1) (float32), one per batch element, h and w alike
    side_h = tf.reshape(tf.clip_by_value(tf.sqrt(crop_scale), 0, 1), shape=(batch_size,))
    side_w = tf.reshape(tf.clip_by_value(tf.sqrt(crop_scale), 0, 1), shape=(batch_size,))
    off_h, off_w = (1 - side_h) / 2, (1 - side_w) / 2  # openvla_utils.py:105-106
    # openvla_utils.py:107-115: boxes [y1, x1, y2, x2] in normalized coordinates
    boxes = tf.stack([off_h, off_w, off_h + side_h, off_w + side_w], axis=1)
    # openvla_utils.py:118: TF's crop_and_resize (bilinear by default) to (224, 224)
    image = tf.image.crop_and_resize(image, boxes, tf.range(batch_size), (224, 224))
    image = image[0]  # openvla_utils.py:121-122
    image = tf.clip_by_value(image, 0, 1)  # openvla_utils.py:150
    image = tf.image.convert_image_dtype(image, orig_dtype, saturate=True)  # openvla_utils.py:151: back to uint8
    return image.numpy()


def request(
    obs: dict,
    task_description: str,
    *,
    resize_size: int | tuple[int, int] = RESIZE_SIZE,
    center_crop: bool = CENTER_CROP,
    task_suite_name: str = TASK_SUITE_NAME,
    unnorm_key: str | None = None,
    resize_fn: Callable[[np.ndarray, tuple[int, int]], np.ndarray] | None = None,
    center_crop_fn: Callable[[np.ndarray], np.ndarray] | None = None,
) -> dict:
    """The payload a REST client doing upstream's LIBERO preprocessing posts to deploy.py's /act (before json-numpy).

    Keys: exactly those deploy.py reads (openvla/openvla@c8f03f4 vla-scripts/deploy.py:99-100): "image" (uint8
    224x224x3, rotated, JPEG round-tripped, resized, center-cropped), "instruction" (the task text as LIBERO gives it:
    the server lower-cases it, deploy.py:62), "unnorm_key".
    """
    if isinstance(resize_size, int):  # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:53-54
        resize_size = (resize_size, resize_size)
    resize_fn = resize_fn or tf_resize_image
    center_crop_fn = center_crop_fn or tf_center_crop

    # openvla/openvla@c8f03f4 experiments/robot/libero/libero_utils.py:55-57: agentview only, rotate, resize
    img = resize_fn(rotate_180(obs["agentview_image"]), resize_size)
    # openvla/openvla@c8f03f4 experiments/robot/openvla_utils.py:129-130: PIL RGB (identity for uint8 HxWx3)
    img = np.array(Image.fromarray(img).convert("RGB"))
    if center_crop:  # openvla/openvla@c8f03f4 experiments/robot/openvla_utils.py:135
        img = center_crop_fn(img)
        # openvla/openvla@c8f03f4 experiments/robot/openvla_utils.py:154-155: PIL RGB again (identity)
        img = np.array(Image.fromarray(img).convert("RGB"))

    # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:101: unnorm_key = task suite name; :110-111
    # switches to f"{key}_no_noops" when only that is in model.norm_stats (a REST client cannot see norm_stats: pass
    # the resolved key as `unnorm_key=`)
    if unnorm_key is None:
        unnorm_key = task_suite_name
    return {"image": img, "instruction": task_description, "unnorm_key": unnorm_key}


def prompt(instruction: str, openvla_path: str = "openvla/openvla-7b") -> str:
    """Server side: the prompt deploy.py builds (openvla/openvla@c8f03f4 vla-scripts/deploy.py:58-62, used at :103).

    Same text as the in-process eval (experiments/robot/openvla_utils.py:158-163, which tests "openvla-v01" instead
    of "v01"). The instruction is lower-cased (str.lower) on the server; nothing else is changed (no strip, no
    trailing-period removal).
    """
    if "v01" in openvla_path:
        system = (
            "A chat between a curious user and an artificial intelligence assistant. "
            "The assistant gives helpful, detailed, and polite answers to the user's questions."
        )
        return f"{system} USER: What action should the robot take to {instruction.lower()}? ASSISTANT:"
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


# ---- server side: predict_action's de-tokenization and un-normalization -------------------------------------------
def bin_centers(n_action_bins: int = 256) -> np.ndarray:
    """float64 (n_action_bins - 1,). openvla/openvla@c8f03f4 prismatic/extern/hf/modeling_prismatic.py:500-501
    (n_action_bins default 256: prismatic/extern/hf/configuration_prismatic.py:135)."""
    bins = np.linspace(-1, 1, n_action_bins)
    return (bins[:-1] + bins[1:]) / 2.0


def detokenize(token_ids: np.ndarray, vocab_size: int = 32000, n_action_bins: int = 256) -> np.ndarray:
    """Server side: the last ACTION_DIM generated token ids -> normalized actions (float64).

    openvla/openvla@c8f03f4 prismatic/extern/hf/modeling_prismatic.py:521-524. `vocab_size` is
    `text_config.vocab_size - pad_to_multiple_of` (:504; pad_to_multiple_of default 64, configuration_prismatic.py:86);
    32000 assumes the checkpoint's text_config.vocab_size is 32064 (checkpoint config, not readable here).
    """
    centers = bin_centers(n_action_bins)
    discretized = vocab_size - np.asarray(token_ids)
    discretized = np.clip(discretized - 1, a_min=0, a_max=centers.shape[0] - 1)
    return centers[discretized]


def unnormalize(normalized_actions: np.ndarray, action_stats: dict) -> np.ndarray:
    """Server side: q01/q99 un-normalization, no epsilon; masked-out dims (the gripper) pass through.

    openvla/openvla@c8f03f4 prismatic/extern/hf/modeling_prismatic.py:527-534. `action_stats` is
    norm_stats[unnorm_key]["action"] as parsed from JSON (config.json for a Hub id, or dataset_statistics.json for a
    local directory: vla-scripts/deploy.py:87-89), so q01/q99 are float64 and the result is float64.
    """
    mask = action_stats.get("mask", np.ones_like(action_stats["q01"], dtype=bool))
    action_high, action_low = np.array(action_stats["q99"]), np.array(action_stats["q01"])
    return np.where(mask, 0.5 * (normalized_actions + 1) * (action_high - action_low) + action_low, normalized_actions)


# ---- out: reply -> env.step (client side) --------------------------------------------------------------------------
def normalize_gripper_action(action: np.ndarray, binarize: bool = True) -> np.ndarray:
    """In place, as upstream (openvla/openvla@c8f03f4 experiments/robot/robot_utils.py:75-92)."""
    orig_low, orig_high = 0.0, 1.0  # robot_utils.py:85
    action[..., -1] = 2 * (action[..., -1] - orig_low) / (orig_high - orig_low) - 1  # robot_utils.py:86
    if binarize:
        action[..., -1] = np.sign(action[..., -1])  # robot_utils.py:88-90
    return action


def invert_gripper_action(action: np.ndarray) -> np.ndarray:
    """In place (openvla/openvla@c8f03f4 experiments/robot/robot_utils.py:95-102)."""
    action[..., -1] = action[..., -1] * -1.0  # robot_utils.py:101
    return action


def executed(reply) -> list:
    """What reaches env.step for one query: one action, a list of 7 Python floats.

    `reply` is deploy.py's answer as the client gets it: `JSONResponse(action)` (vla-scripts/deploy.py:108-109) of the
    float64 (7,) array predict_action returns, json-numpy decoded -> a float64 (7,) ndarray. No chunk: one query per
    env step (openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:186-233).

    json-numpy decodes with np.frombuffer, a READ-ONLY array, and upstream's gripper functions write in place: applied
    to the decoded reply as is they raise (run_libero_eval.py:235-238 would then end the episode). In process, the
    eval gets predict_action's fresh writable array. So the reply is copied first (np.array keeps the dtype and the
    values); every later step is upstream's, in upstream's dtype (float64 for a real reply).
    """
    action = np.array(reply)
    # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:220: [0,1] -> [-1,1], then sign
    action = normalize_gripper_action(action, binarize=True)
    # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:224-225: model_family == "openvla" -> flip
    action = invert_gripper_action(action)
    # openvla/openvla@c8f03f4 experiments/robot/libero/run_libero_eval.py:228: env.step(action.tolist())
    return [action.tolist()]
