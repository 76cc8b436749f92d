"""UniVLA's own LIBERO evaluation, restated from upstream's source only (issue #43).

Written by a separate reader from OpenDriveLab/UniVLA at 0ab9e9d (full commit in SOURCE), without reading
conflictbench's UniVLA plugin. Every step cites `OpenDriveLab/UniVLA@0ab9e9d path:LINE`. The step list with
dtypes is in docs/upstream/univla_client_steps.md.

UniVLA has no server: `experiments/robot/libero/run_libero_eval.py` runs the VLA, the action decoder and LIBERO
in one process. The boundary is therefore drawn by convention (issue #43 brief), not by a wire:

* `request(obs, task_description, **settings)`: everything the eval loop prepares before the VLA forward pass:
  the image it hands to the HF processor (after rotate / JPEG / Lanczos / center crop), the prompt text (with the
  previous query's latent-action tokens), and the proprio vector the loop builds but never feeds the model.
* `Executed` (a class, because upstream keeps a temporal-ensembling buffer across queries; `executed(...)` is a
  thin wrapper around it): everything from the action decoder head's output (a float32 array of 7 * window
  values in (-1, 1), after its final Tanh) to the `env.step` argument: the decoder's own post-processing
  (`decoder_postprocess`), the temporal ensemble, the un-normalization with q01/q99, the gripper steps and
  `.tolist()`. UniVLA's LIBERO loop queries the model at EVERY step and executes ONE ensembled action per query.
* `executed_blocking(...)`: the same for the second loop in the repo, `run_libero_eval_blocking.py` (no
  ensembling, the whole window of 12 actions executed open loop, no history tokens in the prompt).

Only numpy (and, for the image step, TensorFlow and PIL, exactly as upstream's client uses them) are imported.
TensorFlow is imported lazily: importing this module and everything on the action path needs numpy alone.
"""

from __future__ import annotations

import math

import numpy as np

SOURCE = {
    "repository": "OpenDriveLab/UniVLA",
    "commit": "0ab9e9dd3074ffa14fdd1a00aa2aa84e4f8e1352",
    "files": [
        "experiments/robot/libero/run_libero_eval.py",
        "experiments/robot/libero/run_libero_eval_blocking.py",
        "experiments/robot/libero/libero_utils.py",
        "experiments/robot/robot_utils.py",
        "experiments/robot/openvla_utils.py",
        "prismatic/extern/hf/modeling_prismatic.py",
        "prismatic/extern/hf/processing_prismatic.py",
        "prismatic/vla/datasets/rlds/utils/data_utils.py",
        "prismatic/vla/datasets/rlds/oxe/materialize.py",
    ],
}

# --------------------------------------------------------------------------------------------------------------
# Episode constants (run_libero_eval.py and run_libero_eval_blocking.py agree on all of these; neither file has
# changed these values in the repository's history: run_libero_eval.py is unchanged since 9cdedb3, the first
# commit; run_libero_eval_blocking.py was added in ea5a973 and changed once, e2dc615, to add un-normalization).
# --------------------------------------------------------------------------------------------------------------

# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:59 (default suite; also the unnorm key, :180)
DEFAULT_TASK_SUITE = "libero_10"
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:60
NUM_STEPS_WAIT = 10
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:264-273 (blocking: :253-262, same values)
MAX_STEPS = {
    "libero_spatial": 240,
    "libero_object": 300,
    "libero_goal": 320,
    "libero_10": 550,
    "libero_90": 420,
}
# The loop runs `while t < max_steps + num_steps_wait`, t counting the no-op steps too, and t is NOT incremented
# on the step where `done` is true (it breaks first).
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:278, :282-285, :342-346
# No-op action: a list of Python ints, passed to env.step as is.
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/libero_utils.py:28-30
NOOP_ACTION = [0, 0, 0, 0, 0, 0, -1]
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:73 (set_seed_everywhere, robot_utils.py:30-38)
SEED = 7
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/libero_utils.py:18-25
# (resolution=256 from run_libero_eval.py:244)
ENV_RESOLUTION = 256
ENV_SEED = 0
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/robot_utils.py:57-58
RESIZE_SIZE = 224
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:53
CENTER_CROP = True
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/openvla_utils.py:183-184
CROP_SCALE = 0.9
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:62 (ActionDecoder(cfg.window_size), :183)
WINDOW_SIZE = 12
ACTION_DIM = 7
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:131-132
BALANCING_FACTOR = 0.1
# The ensemble weights are np.exp(-1 * 0.1 * i), i = 0..11, each a scalar np.exp call (run_libero_eval.py:132).
# numpy 1.26 (upstream's pin, pyproject.toml:46) computes float64 exp with its own AVX512F routine where the CPU has
# AVX512F, and with libm's exp otherwise; the two differ in the last bit for i = 4, 7, 10 (measured here with numpy
# 1.26.4, and again with NPY_DISABLE_CPU_FEATURES set to the AVX512 features). So upstream's executed actions depend
# on the CPU that runs its eval; these are the two sets of weights, as float.hex():
TEMPORAL_WEIGHTS_HEX = {
    "numpy_avx512f": [
        "0x1.0000000000000p+0", "0x1.cf46d99d52b3ap-1", "0x1.a330ad6166159p-1", "0x1.7b4c869c37c05p-1",
        "0x1.57343067270edp-1", "0x1.368b2fc6f960ap-1", "0x1.18fdd6b9604e3p-1", "0x1.fc80db9dd5542p-2",
        "0x1.cc1ce4581db88p-2", "0x1.a053cc0086e1ep-2", "0x1.78b56362cef39p-2", "0x1.54dc284911bf1p-2",
    ],
    "libm": [
        "0x1.0000000000000p+0", "0x1.cf46d99d52b3ap-1", "0x1.a330ad6166159p-1", "0x1.7b4c869c37c05p-1",
        "0x1.57343067270eep-1", "0x1.368b2fc6f960ap-1", "0x1.18fdd6b9604e3p-1", "0x1.fc80db9dd5541p-2",
        "0x1.cc1ce4581db88p-2", "0x1.a053cc0086e1ep-2", "0x1.78b56362cef38p-2", "0x1.54dc284911bf1p-2",
    ],
}  # fmt: skip
# Default checkpoint path: matters only through the substring test "openvla-v01" in the prompt builder.
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:48; openvla_utils.py:205
DEFAULT_PRETRAINED_CHECKPOINT = "./vla-scripts/libero_log/finetune-libero"
# Actions executed per query: the main loop executes one ensembled action per model query.
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:288-341 (one env.step per iteration)
ACTIONS_PER_QUERY = 1
# The blocking loop executes the whole window before asking again.
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval_blocking.py:276, :315, :318
ACTIONS_PER_QUERY_BLOCKING = WINDOW_SIZE
# Latent-action tokens: '<ACT_0>' .. '<ACT_31>' for token ids 32001 .. 32032.
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:231, :322
NUM_LATENT_ACTION_CODES = 32
LATENT_ACTION_FIRST_ID = 32001
# Sampling settings of the VLA (model side, listed for completeness; they do not enter request/executed):
# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/openvla_utils.py:219; prismatic/extern/hf/modeling_prismatic.py:551
GENERATE_KWARGS = {"do_sample": True, "temperature": 0.75, "top_p": 0.9, "min_new_tokens": 4, "max_new_tokens": 4}

# OpenDriveLab/UniVLA@0ab9e9d experiments/robot/openvla_utils.py:24-28 (only for a checkpoint path with "openvla-v01")
OPENVLA_V01_SYSTEM_PROMPT = (
    "A chat between a curious user and an artificial intelligence assistant. "
    "The assistant gives helpful, detailed, and polite answers to the user's questions."
)


# ==============================================================================================================
# Way in
# ==============================================================================================================


def quat2axisangle(quat):
    """Quaternion (x, y, z, w) -> axis-angle, float64 (3,).

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/libero_utils.py:77-101. Upstream clips quat[3] IN PLACE
    (it mutates obs["robot0_eef_quat"] when |w| > 1); here a copy is clipped, the values are the same.
    """
    q = np.array(quat, copy=True)
    # libero_utils.py:91-94: clip w to [-1, 1]
    if q[3] > 1.0:
        q[3] = 1.0
    elif q[3] < -1.0:
        q[3] = -1.0
    # libero_utils.py:96: float64 scalar arithmetic
    den = np.sqrt(1.0 - q[3] * q[3])
    # libero_utils.py:97-99: math.isclose(den, 0.0) with default tolerances is true only for den == 0.0
    if math.isclose(den, 0.0):
        return np.zeros(3)
    # libero_utils.py:101: ((xyz * 2.0) * acos(w)) / den, left to right
    return (q[:3] * 2.0 * math.acos(q[3])) / den


def proprio_state(obs):
    """The 8-D float64 state the loop builds: eef_pos (3), axis-angle (3), gripper_qpos (2).

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:295-300. It goes into the observation
    dict under "state" but is NEVER read: get_vla_latent_action reads only obs["full_image"]
    (experiments/robot/openvla_utils.py:176); the comment at run_libero_eval.py:294 says "UniVLA does not take
    proprio state as input".
    """
    return np.concatenate((obs["robot0_eef_pos"], quat2axisangle(obs["robot0_eef_quat"]), obs["robot0_gripper_qpos"]))


def jpeg_lanczos_resize(img, resize_size=RESIZE_SIZE):
    """JPEG round trip then Lanczos3 antialiased resize, uint8 out; TensorFlow, as upstream.

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/libero_utils.py:33-47 (TF pinned to 2.15.0 in
    pyproject.toml:61).
    """
    import tensorflow as tf  # upstream's client does this step in TensorFlow

    if isinstance(resize_size, int):  # libero_utils.py:53-54
        resize_size = (resize_size, resize_size)
    # libero_utils.py:42: tf.image.encode_jpeg with its defaults (quality 95, 4:2:0 chroma)
    data = tf.image.encode_jpeg(img)
    # libero_utils.py:43: decode back (TF's decoder, default DCT method)
    x = tf.io.decode_image(data, expand_animations=False, dtype=tf.uint8)
    # libero_utils.py:44: float32 result
    x = tf.image.resize(x, resize_size, method="lanczos3", antialias=True)
    # libero_utils.py:45: round half to even, clip, cast
    x = tf.cast(tf.clip_by_value(tf.round(x), 0, 255), tf.uint8)
    return x.numpy()  # libero_utils.py:46


def libero_image(obs, resize_size=RESIZE_SIZE):
    """The loop's `img` (= observation["full_image"]): agentview rotated 180 degrees, JPEG, Lanczos to 224.

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/libero_utils.py:50-58; the wrist camera is not used.
    """
    img = obs["agentview_image"]  # libero_utils.py:55
    img = img[::-1, ::-1]  # libero_utils.py:56: flip rows and columns (a view with negative strides)
    return jpeg_lanczos_resize(img, resize_size)  # libero_utils.py:57


def center_crop(image_uint8, crop_scale=CROP_SCALE):
    """Center crop of area `crop_scale` (side sqrt(0.9)) bilinearly resized back to 224x224, uint8 out.

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/openvla_utils.py:182-202 and crop_and_resize :82-125.
    """
    import tensorflow as tf  # upstream's client does this step in TensorFlow

    batch_size = 1  # openvla_utils.py:183
    image = tf.convert_to_tensor(np.array(image_uint8))  # openvla_utils.py:187
    orig_dtype = image.dtype  # :188 (tf.uint8)
    image = tf.image.convert_image_dtype(image, tf.float32)  # :191: x / 255 in float32
    # crop_and_resize, openvla_utils.py:95-125
    image = tf.expand_dims(image, axis=0)  # :97-99 (3-D input)
    side = tf.reshape(tf.clip_by_value(tf.sqrt(crop_scale), 0, 1), shape=(batch_size,))  # :102-103
    offset = (1 - side) / 2  # :106-107
    boxes = tf.stack([offset, offset, offset + side, offset + side], axis=1)  # :108-116 [y1, x1, y2, x2]
    # :119: output size is the literal (224, 224), default method bilinear
    image = tf.image.crop_and_resize(image, boxes, tf.range(batch_size), (224, 224))
    image = image[0]  # :122-123
    image = tf.clip_by_value(image, 0, 1)  # openvla_utils.py:197
    # :198: float -> uint8 with saturate=True (TF scales by 255.5 and truncates)
    image = tf.image.convert_image_dtype(image, orig_dtype, saturate=True)
    return image.numpy()  # :201 (then PIL .convert("RGB"), an identity on RGB uint8)


def prompt_text(task_description, hist_action="", pretrained_checkpoint=DEFAULT_PRETRAINED_CHECKPOINT):
    """The prompt string handed to the HF processor.

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/openvla_utils.py:204-213. The task is lower-cased; when the
    history string is not empty it REPLACES the prompt (also for a v01 checkpoint) with the "History action" form.
    """
    task = task_description.lower()
    if "openvla-v01" in pretrained_checkpoint:  # openvla_utils.py:205-208
        prompt = f"{OPENVLA_V01_SYSTEM_PROMPT} USER: What action should the robot take to {task}? ASSISTANT:"
    else:  # openvla_utils.py:209-210
        prompt = f"In: What action should the robot take to {task}?\nOut:"
    if len(hist_action) > 0:  # openvla_utils.py:212-213
        prompt = f"In: What action should the robot take to {task}? History action {hist_action}\nOut:"
    return prompt


def history_string(generated_ids):
    """The history string recorded after a query, from the 4 latent-action token ids the VLA returned.

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:231, :320-323: '<ACT_{id - 32001}>'
    concatenated without separators. Upstream indexes a Python list, so an id below 32001 would wrap around
    (negative index) and one above 32032 raises IndexError, which ends the episode (the loop's `except`, :348-351).
    Only the LAST query's string is used by the next query (run_libero_eval.py:316, `prev_hist_action[-1]`);
    the "last 4 entries" string built at :303-307 is never used.
    """
    codes = [f"<ACT_{i}>" for i in range(NUM_LATENT_ACTION_CODES)]
    return "".join(codes[int(token_id) - LATENT_ACTION_FIRST_ID] for token_id in np.asarray(generated_ids).reshape(-1))


def request(
    obs,
    task_description,
    *,
    hist_action="",
    resize_size=RESIZE_SIZE,
    center_crop_image=CENTER_CROP,
    pretrained_checkpoint=DEFAULT_PRETRAINED_CHECKPOINT,
):
    """What upstream's LIBERO loop prepares for one VLA query (before `processor(prompt, image)`).

    `hist_action`: '' for the first query of an episode (run_libero_eval.py:256, prev_hist_action = ['']), then
    `history_string(generated_ids)` of the previous query (main loop); ALWAYS '' in the blocking loop
    (run_libero_eval_blocking.py:300).

    Returns a dict:
      "image":      uint8 (224, 224, 3), the pixels of the PIL image passed to the processor (after center crop);
      "prompt":     str, the text passed to the processor;
      "full_image": uint8 (224, 224, 3), observation["full_image"] (before the crop; also the replay frame);
      "state":      float64 (8,), observation["state"], built but never consumed by the model.
    """
    from PIL import Image  # upstream wraps the array in PIL before cropping (openvla_utils.py:176-177)

    full_image = libero_image(obs, resize_size)  # run_libero_eval.py:288
    state = proprio_state(obs)  # run_libero_eval.py:295-300
    # openvla_utils.py:176-177: PIL RGB (identity for HxWx3 uint8)
    image = np.array(Image.fromarray(full_image).convert("RGB"))
    if center_crop_image:  # openvla_utils.py:182
        image = np.array(Image.fromarray(center_crop(image)).convert("RGB"))  # :201-202
    prompt = prompt_text(task_description, hist_action, pretrained_checkpoint)
    return {"image": image, "prompt": prompt, "full_image": full_image, "state": state}


# ==============================================================================================================
# Way out
# ==============================================================================================================


def action_stats(norm_stats, task_suite_name=DEFAULT_TASK_SUITE):
    """(mask, action_low, action_high) as the loop reads them from the parsed dataset_statistics.json.

    norm_stats: the parsed JSON (`json.load` of <checkpoint>/dataset_statistics.json, openvla_utils.py:61-65).
    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:180 (key = suite name), :194-196
    (fall back to "<suite>_no_noops"), :326-328; modeling_prismatic.py:573-596 (get_action_stats asserts the key
    and returns norm_stats[key]["action"]).
    The mask stays what JSON gave (a list of Python bools; [True]*6 + [False] for LIBERO, oxe/materialize.py:39),
    or an all-True bool array when absent; low/high are np.array of the JSON floats (float64).
    """
    key = task_suite_name
    if key not in norm_stats and f"{key}_no_noops" in norm_stats:
        key = f"{key}_no_noops"
    if key not in norm_stats:
        raise KeyError(f"Action un-norm key {key} not found in VLA `norm_stats`!")
    stats = norm_stats[key]["action"]
    mask = stats.get("mask", np.ones_like(stats["q01"], dtype=bool))
    return mask, np.array(stats["q01"]), np.array(stats["q99"])


def decoder_postprocess(head_output, window_size=WINDOW_SIZE):
    """The action decoder's own post-processing of its head output: reshape to (-1, window, 7), to float64.

    head_output: the float32 output of ActionDecoderHead (its last layer is Tanh, run_libero_eval.py:106-109),
    shape (1, 7 * window) (or anything that reshapes to it).
    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:142-143: `.reshape(-1, T, 7)`, then
    `np.array(tensor.tolist())`: every float32 goes through a Python float, so the result is float64 holding the
    float32 values exactly.
    """
    arr = np.asarray(head_output)
    return np.array(arr.reshape(-1, window_size, ACTION_DIM).tolist())


def gripper_steps(action):
    """normalize_gripper_action(binarize=True) then invert_gripper_action, in place on a float64 (7,) array.

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/robot_utils.py:85-102 and :105-112; called at
    run_libero_eval.py:333 and :337-338 (model_family "openvla", the default, :47).
    g -> 2 * (g - 0.0) / (1.0 - 0.0) - 1 -> np.sign (0 stays 0) -> * -1.0 (so 0 becomes -0.0).
    """
    orig_low, orig_high = 0.0, 1.0  # robot_utils.py:95
    action[..., -1] = 2 * (action[..., -1] - orig_low) / (orig_high - orig_low) - 1  # :96
    action[..., -1] = np.sign(action[..., -1])  # :98-100
    action[..., -1] = action[..., -1] * -1.0  # :111
    return action


class TemporalEnsemble:
    """ActionDecoder's buffer, ensemble and un-normalization (everything in it except the network).

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval.py:119-165. All float64.
    """

    def __init__(self, window_size=WINDOW_SIZE, weights=None):
        """weights: None computes them as upstream does on THIS machine; "numpy_avx512f" or "libm" pins one of
        the two sets in TEMPORAL_WEIGHTS_HEX (for window 12) whatever the CPU."""
        t = window_size
        self.window_size = t
        # :125: torch.flip(torch.triu(ones(T, T, bool)), dims=[1]): row i is True in columns 0 .. T-1-i
        self.temporal_mask = np.flip(np.triu(np.ones((t, t), dtype=bool)), axis=1).copy()
        if weights is None:
            # :131-132: exp(-0.1 * i), each a scalar np.exp call on the Python float -1 * 0.1 * i, shaped (T, 1)
            self.temporal_weights = np.array([np.exp(-1 * BALANCING_FACTOR * i) for i in range(t)])[:, None]
        else:
            self.temporal_weights = np.array([float.fromhex(h) for h in TEMPORAL_WEIGHTS_HEX[weights]])[:, None]
        self.reset()

    def reset(self):
        """run_libero_eval.py:135-137, called at each episode start (:254)."""
        t = self.window_size
        self.action_buffer = np.zeros((t, t, ACTION_DIM))  # float64
        self.action_buffer_mask = np.zeros((t, t), dtype=np.bool_)

    def __call__(self, pred_action, mask, action_low, action_high):
        """pred_action: decoder_postprocess output, float64 (1, T, 7). Returns float64 (7,)."""
        # :146-149: shift older predictions one row down (axis 0) and one step earlier (axis 1); numpy slice
        # assignment between overlapping views behaves as if the source were copied first.
        self.action_buffer[1:, :, :] = self.action_buffer[:-1, :, :].copy()
        self.action_buffer_mask[1:, :] = self.action_buffer_mask[:-1, :].copy()
        self.action_buffer[:, :-1, :] = self.action_buffer[:, 1:, :].copy()
        self.action_buffer_mask[:, :-1] = self.action_buffer_mask[:, 1:].copy()
        # :150: bool * bool (logical and); forgets predictions past their window
        self.action_buffer_mask = self.action_buffer_mask * self.temporal_mask
        # :153-154: the newest prediction (the (1, T, 7) array broadcast into row 0)
        self.action_buffer[0] = pred_action
        self.action_buffer_mask[0] = np.array([True] * self.window_size, dtype=np.bool_)
        # :157: weighted mean over the predictions for the current step, same numpy reductions and shapes
        # (numerator: (T, 7) summed over axis 0; denominator: (T, 1) summed whole)
        current = self.action_buffer[:, 0, :]
        valid = self.action_buffer_mask[:, 0:1]
        ensembled = np.sum(current * valid * self.temporal_weights, axis=0) / np.sum(valid * self.temporal_weights)
        # :159-163: un-normalize the masked dims: ((0.5 * (x + 1)) * (high - low)) + low; others (gripper) as is
        return np.where(mask, 0.5 * (ensembled + 1) * (action_high - action_low) + action_low, ensembled)


class Executed:
    """From the decoder head's float32 output to the actions passed to env.step, for UniVLA's main LIBERO loop.

    Stateful (temporal ensembling across queries): make one per episode, or call `reset()` at each episode start
    (run_libero_eval.py:254). Each call returns a list with ONE action (a list of 7 Python floats, exactly
    `action.tolist()` as passed to env.step at run_libero_eval.py:341); the loop queries the model again at the
    next step.
    """

    def __init__(self, norm_stats, task_suite_name=DEFAULT_TASK_SUITE, window_size=WINDOW_SIZE, weights=None):
        self.mask, self.action_low, self.action_high = action_stats(norm_stats, task_suite_name)
        self.window_size = window_size
        self.ensemble = TemporalEnsemble(window_size, weights)

    def reset(self):
        self.ensemble.reset()

    def __call__(self, model_output):
        pred_action = decoder_postprocess(model_output, self.window_size)  # run_libero_eval.py:142-143
        action = self.ensemble(pred_action, self.mask, self.action_low, self.action_high)  # :330, :146-163
        action = gripper_steps(action)  # :333, :337-338
        return [action.tolist()]  # :341


def executed(
    model_output, *, norm_stats, task_suite_name=DEFAULT_TASK_SUITE, window_size=WINDOW_SIZE, state=None, weights=None
):
    """Function form of `Executed`: pass the same `state` (an Executed) for every query of an episode.

    Without `state` this is the FIRST query of an episode (empty buffer): the executed action is then the
    un-normalized first row of the window.
    """
    if state is None:
        state = Executed(norm_stats, task_suite_name, window_size, weights)
    return state(model_output)


def executed_blocking(model_output, *, norm_stats, task_suite_name=DEFAULT_TASK_SUITE, window_size=WINDOW_SIZE):
    """run_libero_eval_blocking.py: the whole window, executed open loop, in order (stateless).

    OpenDriveLab/UniVLA@0ab9e9d experiments/robot/libero/run_libero_eval_blocking.py:140-154 (decoder: reshape,
    float64, per-row un-normalization, no ensemble), :276 and :315-318 (queue of T rows, query only when empty),
    :321-329 (gripper steps and .tolist() per row). Returns T lists of 7 Python floats.
    """
    mask, action_low, action_high = action_stats(norm_stats, task_suite_name)
    pred_action = decoder_postprocess(model_output, window_size)[0]  # :142-146, float64 (T, 7)
    for i in range(pred_action.shape[0]):  # :147-152
        row = pred_action[i]
        pred_action[i] = np.where(mask, 0.5 * (row + 1) * (action_high - action_low) + action_low, row)
    out = []
    for row in pred_action:  # :315 deque.extend over the rows, :318 popleft
        out.append(gripper_steps(row).tolist())  # :321, :325-326, :329
    return out
