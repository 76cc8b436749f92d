"""OpenVLA-OFT's LIBERO client, restated from upstream's source by a separate reader (issue #43).

Written from moojink/openvla-oft@213c5ff only (no conflictbench code was read). Every step cites
`moojink/openvla-oft@213c5ff <file>:<line>`; the step list in prose is docs/upstream/openvla_client_steps.md.

What "upstream's LIBERO client" is here. Upstream's LIBERO eval (`run_libero_eval.py`) runs the model in process.
Its REST form is upstream's own: `get_action_from_server` (experiments/robot/openvla_utils.py:801-818) posts the
observation dict, and the server (`vla-scripts/deploy.py` `get_server_action`) runs the very same `get_vla_action`
the in-process eval runs, on the payload. So the client keeps `prepare_observation` (rotate, JPEG + resize) and
adds `"instruction"` as upstream's ALOHA REST client does (experiments/robot/aloha/run_aloha_eval.py:195); the
server does the center crop, the proprio normalization, the prompt, the model and the un-normalization.

    client  obs -> rotate 180° (both cameras) -> TF JPEG round trip + TF lanczos3 resize (both) -> 8-D float64
            state -> payload {"full_image", "wrist_image", "state", "instruction"}
    server  skip resize (already 224) -> PIL RGB -> TF center crop (every image) -> prompt (lower-cased) ->
            normalize_proprio (float64) -> predict_action (L1 head float32 -> `unnormalize` float64 (8, 7))
            -> list of 8 float64 (7,) arrays
    client  reply -> deque(maxlen=num_open_loop_steps).extend -> per env step: popleft ->
            normalize_gripper_action (copy) -> invert_gripper_action (copy) -> env.step(action.tolist())

No state crosses queries (the queue is empty whenever the server is asked again, and a new queue is made per
episode), so `executed` is a function, not a class.

TensorFlow steps are TF's own kernels: the JPEG + resize is called in `tf_resize_image` exactly as upstream calls it
(lazy import; TF is not installed in the test venv; `request(resize_fn=...)` substitutes it). The center crop is
server side here; `tf_center_crop` restates it for reference.

`predict_action` is model code. For a local checkpoint directory the repository's modeling_prismatic.py is copied
into the checkpoint and runs (openvla_utils.py:270-279, :168-198), so `unnormalize` below restates what runs. For an
HF Hub checkpoint (moojink/openvla-7b-oft-finetuned-libero-*, the ones LIBERO.md evaluates) the checkpoint's own
modeling_prismatic.py runs behind `trust_remote_code` (openvla_utils.py:282-290): not readable here, unverified.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np
from PIL import Image

SOURCE = {
    "repository": "moojink/openvla-oft",
    "commit": "213c5ff8d6e9673885d7e4dd6f2ce73b5d8a45db",
    "files": [
        "experiments/robot/libero/run_libero_eval.py",
        "experiments/robot/libero/libero_utils.py",
        "experiments/robot/robot_utils.py",
        "experiments/robot/openvla_utils.py",
        "experiments/robot/aloha/run_aloha_eval.py",
        "vla-scripts/deploy.py",
        "prismatic/vla/constants.py",
        "prismatic/extern/hf/modeling_prismatic.py",
    ],
}

# ---- episode constants -------------------------------------------------------------------------------------------
ENV_RESOLUTION = 256  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:116 (env_img_res), :384
ENV_SEED = 0  # moojink/openvla-oft@213c5ff experiments/robot/libero/libero_utils.py:24 (env.seed(0))
NUM_STEPS_WAIT = 10  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:113
DUMMY_ACTION = [0, 0, 0, 0, 0, 0, -1]  # moojink/openvla-oft@213c5ff experiments/robot/libero/libero_utils.py:28-30
# policy steps per episode; loop while t < MAX_STEPS[suite] + NUM_STEPS_WAIT
# moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:63-69 (bound at :316)
MAX_STEPS = {
    "libero_spatial": 220,
    "libero_object": 280,
    "libero_goal": 300,
    "libero_10": 520,
    "libero_90": 400,
}
NUM_TRIALS_PER_TASK = 50  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:114
SEED = 7  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:128
TASK_SUITE_NAME = "libero_spatial"  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:112
RESIZE_SIZE = 224  # moojink/openvla-oft@213c5ff experiments/robot/robot_utils.py:32-35 (MODEL_IMAGE_SIZES["openvla"])
NUM_OPEN_LOOP_STEPS = 8  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:100
NUM_ACTIONS_CHUNK = 8  # moojink/openvla-oft@213c5ff prismatic/vla/constants.py:27 (LIBERO; selected at :49-68)
ACTION_DIM = 7  # moojink/openvla-oft@213c5ff prismatic/vla/constants.py:28
PROPRIO_DIM = 8  # moojink/openvla-oft@213c5ff prismatic/vla/constants.py:29; run_libero_eval.py:157
NORMALIZATION_TYPE = "bounds_q99"  # moojink/openvla-oft@213c5ff prismatic/vla/constants.py:30
NUM_IMAGES_IN_INPUT = 2  # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:96
CENTER_CROP = True  # moojink/openvla-oft@213c5ff run_libero_eval.py:99 and vla-scripts/deploy.py:132
CROP_SCALE = 0.9  # moojink/openvla-oft@213c5ff experiments/robot/openvla_utils.py:607
SERVER_PORT = 8777  # moojink/openvla-oft@213c5ff vla-scripts/deploy.py:116
# The server's own config must match the LIBERO eval: deploy.py's DeployConfig defaults num_images_in_input=3
# (deploy.py:129, ALOHA's value; LIBERO needs 2) and unnorm_key="" (deploy.py:136, asserted present at :68), and
# prismatic/vla/constants.py picks LIBERO constants when "libero" is in the server's command line or nothing else
# matches (constants.py:49-60): a command line containing "aloha" or "bridge" but not "libero" changes the chunk.
# Revisions: before 72f94a8 (2025-04-27) get_vla_action returned only the first min(8, num_open_loop_steps) actions
# (server side); since, all NUM_ACTIONS_CHUNK come back and the client's deque(maxlen=...) keeps the LAST
# num_open_loop_steps of them (see `executed`). Identical at the default 8. 3758245 (public release) -> 213c5ff
# changed nothing else in the steps restated here (lora_rank, diffusion step counts, video names, HF checkpoints).


# ---- in: observation -> payload (client side) ---------------------------------------------------------------------
def quat2axisangle(quat: np.ndarray) -> np.ndarray:
    """xyzw quaternion -> axis-angle in upstream's order (float64). Upstream clips quat[3] in place; here a copy.

    moojink/openvla-oft@213c5ff experiments/robot/libero/libero_utils.py:63-87
    """
    quat = np.array(quat, copy=True)
    if quat[3] > 1.0:  # libero_utils.py:77-80
        quat[3] = 1.0
    elif quat[3] < -1.0:
        quat[3] = -1.0
    den = np.sqrt(1.0 - quat[3] * quat[3])  # libero_utils.py:82
    if math.isclose(den, 0.0):  # libero_utils.py:83-85 (default tolerances: true only for den == 0.0)
        return np.zeros(3)
    return (quat[:3] * 2.0 * math.acos(quat[3])) / den  # libero_utils.py:87


def libero_state(obs: dict) -> np.ndarray:
    """8-D float64: eef_pos (3) + axis-angle (3) + gripper_qpos (2), raw (normalized by the server).

    moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:257-259
    """
    return np.concatenate((obs["robot0_eef_pos"], quat2axisangle(obs["robot0_eef_quat"]), obs["robot0_gripper_qpos"]))


def rotate_180(img: np.ndarray) -> np.ndarray:
    """`img[::-1, ::-1]` (numpy view). moojink/openvla-oft@213c5ff experiments/robot/libero/libero_utils.py:36, :43"""
    return img[::-1, ::-1]


def tf_resize_image(img: np.ndarray, resize_size: int | tuple[int, int]) -> np.ndarray:
    """TensorFlow's JPEG round trip + lanczos3 resize as upstream calls them (uint8 in, uint8 out).

    moojink/openvla-oft@213c5ff experiments/robot/openvla_utils.py:520-543 (`resize_image_for_policy`)
    """
    import tensorflow as tf  # TF's ops; not installed in conflictbench's test venv

    if isinstance(resize_size, int):  # openvla_utils.py:533-535
        resize_size = (resize_size, resize_size)
    data = tf.image.encode_jpeg(img)  # openvla_utils.py:538: TF's encoder, TF defaults (quality 95)
    decoded = tf.io.decode_image(data, expand_animations=False, dtype=tf.uint8)  # openvla_utils.py:539: TF's decoder
    resized = tf.image.resize(decoded, resize_size, method="lanczos3", antialias=True)  # openvla_utils.py:540 (float32)
    out = tf.cast(tf.clip_by_value(tf.round(resized), 0, 255), tf.uint8)  # openvla_utils.py:541 (half to even)
    return out.numpy()  # openvla_utils.py:543


def request(
    obs: dict,
    task_description: str,
    *,
    resize_size: int | tuple[int, int] = RESIZE_SIZE,
    resize_fn: Callable[[np.ndarray, int | tuple[int, int]], np.ndarray] | None = None,
) -> dict:
    """The observation dict posted to deploy.py's /act (before json-numpy), keys in this order.

    "full_image" / "wrist_image": uint8 (224, 224, 3), rotated + TF JPEG + TF resize, NOT center-cropped (the server
    crops). "state": float64 (8,), raw. "instruction": the task text as LIBERO gives it (the server lower-cases it).
    No "unnorm_key": the server takes it from its own command line (deploy.py:136, used at openvla_utils.py:776, :788).
    """
    resize_fn = resize_fn or tf_resize_image
    # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:243-262 (`prepare_observation`)
    img = rotate_180(obs["agentview_image"])  # :246 -> libero_utils.py:33-37
    wrist_img = rotate_180(obs["robot0_eye_in_hand_image"])  # :247 -> libero_utils.py:40-44
    observation = {
        "full_image": resize_fn(img, resize_size),  # :250, :255
        "wrist_image": resize_fn(wrist_img, resize_size),  # :251, :256
        "state": libero_state(obs),  # :257-259
    }
    # moojink/openvla-oft@213c5ff experiments/robot/aloha/run_aloha_eval.py:195: the REST client adds the instruction
    # to the observation; vla-scripts/deploy.py:86 reads it from there
    observation["instruction"] = task_description
    return observation


# ---- server side (reference): images, prompt, proprio, un-normalization -------------------------------------------
def tf_center_crop(img: np.ndarray, crop_scale: float = CROP_SCALE) -> np.ndarray:
    """Server side: TF's center crop as upstream calls it (uint8 in, uint8 224x224x3 out).

    moojink/openvla-oft@213c5ff experiments/robot/openvla_utils.py:596-626 with `crop_and_resize` at :546-593.
    """
    import tensorflow as tf  # TF's ops

    batch_size = 1  # openvla_utils.py:606
    image = tf.convert_to_tensor(np.array(img))  # openvla_utils.py:610-611
    orig_dtype = image.dtype  # :613
    image = tf.image.convert_image_dtype(image, tf.float32)  # :616
    image = tf.expand_dims(image, axis=0)  # :563-565
    side_h = tf.reshape(tf.clip_by_value(tf.sqrt(crop_scale), 0, 1), shape=(batch_size,))  # :568
    side_w = tf.reshape(tf.clip_by_value(tf.sqrt(crop_scale), 0, 1), shape=(batch_size,))  # :569
    off_h, off_w = (1 - side_h) / 2, (1 - side_w) / 2  # :572-573
    boxes = tf.stack([off_h, off_w, off_h + side_h, off_w + side_w], axis=1)  # :574-582
    image = tf.image.crop_and_resize(image, boxes, tf.range(batch_size), (224, 224))  # :585-587 (OPENVLA_IMAGE_SIZE)
    image = image[0]  # :590-591
    image = tf.clip_by_value(image, 0, 1)  # :622
    image = tf.image.convert_image_dtype(image, orig_dtype, saturate=True)  # :623
    return np.array(Image.fromarray(image.numpy()).convert("RGB"))  # :626 (PIL RGB, identity for uint8 RGB)


def server_images(
    payload: dict,
    *,
    num_images_in_input: int = NUM_IMAGES_IN_INPUT,
    center_crop: bool = CENTER_CROP,
    resize_fn=None,
    center_crop_fn=None,
) -> list[np.ndarray]:
    """Server side: the images the processor gets, in order (primary first, then every key containing "wrist").

    moojink/openvla-oft@213c5ff experiments/robot/openvla_utils.py:746-754 and `prepare_images_for_vla` :682-712:
    uint8 HxWx3 asserted (:629-646), resized only when not (224, 224, 3) (:700-701), PIL RGB (:704), center crop when
    cfg.center_crop (:707-708).
    """
    resize_fn = resize_fn or tf_resize_image
    center_crop_fn = center_crop_fn or tf_center_crop
    images = [payload["full_image"]]
    if num_images_in_input > 1:
        images.extend([payload[k] for k in payload.keys() if "wrist" in k])
    out = []
    for image in images:
        assert isinstance(image, np.ndarray) and image.ndim == 3 and image.shape[-1] == 3 and image.dtype == np.uint8
        if image.shape != (224, 224, 3):
            image = resize_fn(image, 224)
        image = np.array(Image.fromarray(image).convert("RGB"))
        if center_crop:
            image = center_crop_fn(image)
        out.append(image)
    return out


def prompt(instruction: str) -> str:
    """Server side (moojink/openvla-oft@213c5ff experiments/robot/openvla_utils.py:757): str.lower() only."""
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


def normalize_proprio(proprio: np.ndarray, proprio_stats: dict, normalization_type: str = NORMALIZATION_TYPE):
    """Server side: raw float64 state -> [-1, 1] (float64), with +1e-8 and a clip over every dim.

    moojink/openvla-oft@213c5ff experiments/robot/openvla_utils.py:649-679 (stats: norm_stats[unnorm_key]["proprio"],
    :776, parsed from dataset_statistics.json, :352-371). predict_action then makes it torch.Tensor (float32) and
    casts to the model dtype (bf16): prismatic/extern/hf/modeling_prismatic.py:1008.
    """
    if normalization_type == "bounds":
        mask = proprio_stats.get("mask", np.ones_like(proprio_stats["min"], dtype=bool))
        high, low = np.array(proprio_stats["max"]), np.array(proprio_stats["min"])
    elif normalization_type == "bounds_q99":
        mask = proprio_stats.get("mask", np.ones_like(proprio_stats["q01"], dtype=bool))
        high, low = np.array(proprio_stats["q99"]), np.array(proprio_stats["q01"])
    else:
        raise ValueError(normalization_type)
    return np.clip(np.where(mask, 2 * (proprio - low) / (high - low + 1e-8) - 1, proprio), a_min=-1.0, a_max=1.0)


def unnormalize(normalized_actions: np.ndarray, action_stats: dict, normalization_type: str = NORMALIZATION_TYPE):
    """Server side: (8, 7) normalized actions -> un-normalized, with +1e-8 (absent in OpenVLA); mask dims pass through.

    moojink/openvla-oft@213c5ff prismatic/extern/hf/modeling_prismatic.py:772-791. The L1 head's output is float32
    (`.float().cpu().numpy()`, :919-925); `0.5 * (a + 1)` stays float32, the product with the float64 JSON statistics
    promotes to float64, and np.where(mask, float64, float32) is float64: the reply is float64 (8, 7).
    """
    if normalization_type == "bounds":
        mask = action_stats.get("mask", np.ones_like(action_stats["min"], dtype=bool))
        high, low = np.array(action_stats["max"]), np.array(action_stats["min"])
    elif normalization_type == "bounds_q99":
        mask = action_stats.get("mask", np.ones_like(action_stats["q01"], dtype=bool))
        high, low = np.array(action_stats["q99"]), np.array(action_stats["q01"])
    else:
        raise ValueError(normalization_type)
    return np.where(mask, 0.5 * (normalized_actions + 1) * (high - low + 1e-8) + low, normalized_actions)


def server_reply(actions: np.ndarray) -> list[np.ndarray]:
    """Server side: the chunk as a list of its rows (views), JSONResponse'd; moojink/openvla-oft@213c5ff
    experiments/robot/openvla_utils.py:798, vla-scripts/deploy.py:92-95."""
    return [actions[i] for i in range(len(actions))]


# ---- out: reply -> env.step (client side) --------------------------------------------------------------------------
def normalize_gripper_action(action: np.ndarray, binarize: bool = True) -> np.ndarray:
    """On a copy (moojink/openvla-oft@213c5ff experiments/robot/robot_utils.py:149-177)."""
    normalized_action = action.copy()  # :167
    orig_low, orig_high = 0.0, 1.0  # :170
    normalized_action[..., -1] = 2 * (normalized_action[..., -1] - orig_low) / (orig_high - orig_low) - 1  # :171
    if binarize:
        normalized_action[..., -1] = np.sign(normalized_action[..., -1])  # :173-175
    return normalized_action


def invert_gripper_action(action: np.ndarray) -> np.ndarray:
    """On a copy (moojink/openvla-oft@213c5ff experiments/robot/robot_utils.py:180-199)."""
    inverted_action = action.copy()  # :194
    inverted_action[..., -1] *= -1.0  # :197
    return inverted_action


def executed(reply, *, num_open_loop_steps: int = NUM_OPEN_LOOP_STEPS) -> list:
    """What reaches env.step, in order, until the client asks again: lists of 7 Python floats.

    `reply` is the server's list of float64 (7,) arrays as json-numpy decodes it (read-only arrays: fine, upstream's
    gripper functions copy first).
    """
    # moojink/openvla-oft@213c5ff experiments/robot/libero/run_libero_eval.py:306: a bounded deque, made per episode
    action_queue = deque(maxlen=num_open_loop_steps)
    # :328-341: queried only when the queue is empty; extend() on a bounded deque drops from the LEFT, so with
    # num_open_loop_steps < len(reply) the LAST num_open_loop_steps actions are kept (all 8 at the default)
    action_queue.extend(reply)
    out = []
    while len(action_queue) > 0:  # the next query happens at the first step that finds the queue empty (:328)
        action = action_queue.popleft()  # :344
        # :347 -> process_action :265-275: normalize (binarize) then invert (model_family == "openvla")
        action = normalize_gripper_action(action, binarize=True)
        action = invert_gripper_action(action)
        out.append(action.tolist())  # :350: env.step(action.tolist())
    return out
