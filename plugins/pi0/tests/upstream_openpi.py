"""openpi's own LIBERO client (π0, π0-FAST, π0.5), restated from upstream's source alone (issue #43).

Written by a separate reader who did not open conflictbench's π plugin, so that a test comparing the plugin with
this module compares it with upstream, not with itself. Nothing here imports conflictbench: only numpy, PIL (what
upstream's `openpi_client.image_tools` resizes with) and `math` (what upstream's `_quat2axisangle` uses); msgpack
only inside `encode` / `decode`, which restate the wire format and are optional.

Every step cites `owner/name@<7 hex> path:LINE` at the pinned commit (SOURCE). Short names used below:
  main.py      = examples/libero/main.py
  image_tools  = packages/openpi-client/src/openpi_client/image_tools.py
  msgpack_np   = packages/openpi-client/src/openpi_client/msgpack_numpy.py
  ws_client    = packages/openpi-client/src/openpi_client/websocket_client_policy.py

Upstream keeps no state across queries that changes what is sent or executed: its `action_plan` deque is refilled
only when empty and always with exactly `replan_steps` actions (main.py:127-150), so each query is fully described
by `request` (what goes out) and `executed` (what comes back to `env.step`). No class is needed.

Versions upstream's LIBERO client pins (examples/libero/requirements.txt at the same commit): numpy==1.22.4 (:47),
pillow==10.4.0 (:64), robosuite==1.4.1 (:90); openpi-client itself requires numpy<2 and pillow>=9
(packages/openpi-client/pyproject.toml:5-11). The arithmetic below follows whatever numpy / PIL runs it: every
array upstream builds from LIBERO's observation is float64 or uint8, where numpy 1.x and 2.x agree.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image

SOURCE = {
    "repository": "Physical-Intelligence/openpi",
    "commit": "15a9616a00943ada6c20a0f158e3adb39df2ccac",
    "files": [
        "examples/libero/main.py",
        "examples/libero/requirements.txt",
        "packages/openpi-client/src/openpi_client/image_tools.py",
        "packages/openpi-client/src/openpi_client/websocket_client_policy.py",
        "packages/openpi-client/src/openpi_client/msgpack_numpy.py",
        "src/openpi/serving/websocket_policy_server.py",
        "scripts/serve_policy.py",
        "src/openpi/policies/policy_config.py",
        "src/openpi/policies/policy.py",
        "src/openpi/policies/libero_policy.py",
        "src/openpi/training/config.py",
    ],
}

# ---------------------------------------------------------------------------------------------------------------------
# Episode constants. examples/libero/main.py has one revision only (231a1cf, the initial commit) up to the pinned
# commit, so none of these differ between revisions; image_tools.py and msgpack_numpy.py likewise.
# ---------------------------------------------------------------------------------------------------------------------

# The no-op sent during the warm-up: six zeros and gripper -1.0 (open), a Python list of floats.
# Physical-Intelligence/openpi@15a9616 examples/libero/main.py:17
DUMMY_ACTION = [0.0] * 6 + [-1.0]
# Camera height and width LIBERO renders at (camera_heights / camera_widths of OffScreenRenderEnv).
# Physical-Intelligence/openpi@15a9616 examples/libero/main.py:18, :85, :193
ENV_RESOLUTION = 256
# Client defaults. Physical-Intelligence/openpi@15a9616 examples/libero/main.py:28 (resize_size), :29 (replan_steps),
# :37 (num_steps_wait), :38 (num_trials_per_task), :45 (seed: np.random.seed at :50, env.seed at :195)
RESIZE_SIZE = 224
REPLAN_STEPS = 5
NUM_STEPS_WAIT = 10
NUM_TRIALS_PER_TASK = 50
SEED = 7
# Policy steps per suite (the loop runs while t < max_steps + num_steps_wait, t counting the warm-up steps too, so
# at most max_steps policy actions are executed). Any other suite name raises ValueError.
# Physical-Intelligence/openpi@15a9616 examples/libero/main.py:60-71, loop bound :104
MAX_STEPS = {
    "libero_spatial": 220,  # main.py:61
    "libero_object": 280,  # main.py:63
    "libero_goal": 300,  # main.py:65
    "libero_10": 520,  # main.py:67
    "libero_90": 400,  # main.py:69
}
DEFAULT_SUITE = "libero_spatial"  # main.py:34-36

# The keys upstream's client sends, in the order its dict literal inserts them (msgpack keeps that order on the wire).
# Physical-Intelligence/openpi@15a9616 examples/libero/main.py:130-141
REQUEST_KEYS = ("observation/image", "observation/wrist_image", "observation/state", "prompt")


# ---------------------------------------------------------------------------------------------------------------------
# Observation -> request
# ---------------------------------------------------------------------------------------------------------------------


def quat2axisangle(quat: np.ndarray) -> np.ndarray:
    """LIBERO's xyzw quaternion to axis-angle, in upstream's order of operations and dtype.

    Physical-Intelligence/openpi@15a9616 examples/libero/main.py:199-214 (a copy of robosuite's quat2axisangle).
    Upstream clips w into [-1, 1] by assigning into the array it is given, i.e. into obs["robot0_eef_quat"] itself
    (main.py:204-207); this restatement clips a copy, so the value is the same and the caller's obs is left as is.
    With LIBERO's float64 quaternion every intermediate is float64 and so is the result.
    """
    q = np.array(quat, copy=True)
    # main.py:204-207: clamp w, written back into the array (same dtype as the array).
    if q[3] > 1.0:
        q[3] = 1.0
    elif q[3] < -1.0:
        q[3] = -1.0
    # main.py:209: numpy scalar arithmetic, 1.0 - w*w, then np.sqrt (np.float64 for a float64 quaternion).
    den = np.sqrt(1.0 - q[3] * q[3])
    # main.py:210-212: math.isclose with its defaults (rel_tol=1e-9, abs_tol=0.0) against 0.0 is true only when
    # den == 0.0 exactly (|w| == 1); then a fresh np.zeros(3), float64 whatever the quaternion's dtype.
    if math.isclose(den, 0.0):
        return np.zeros(3)
    # main.py:214: ((xyz * 2.0) * math.acos(w)) / den, left to right; math.acos returns a Python float.
    angle = math.acos(q[3])
    return ((q[:3] * 2.0) * angle) / den


def state(obs: dict) -> np.ndarray:
    """The 8-vector upstream sends as "observation/state": eef position (3), axis-angle (3), gripper qpos (2).

    Physical-Intelligence/openpi@15a9616 examples/libero/main.py:133-139: np.concatenate of the three, no cast, so
    float64 (8,) from LIBERO's float64 observation.
    """
    return np.concatenate((obs["robot0_eef_pos"], quat2axisangle(obs["robot0_eef_quat"]), obs["robot0_gripper_qpos"]))


def _pad_geometry(cur_w: int, cur_h: int, width: int, height: int) -> tuple[int, int, int, int]:
    """Size of the resized image and its offset inside the zero canvas, as image_tools computes them.

    Physical-Intelligence/openpi@15a9616 packages/openpi-client/src/openpi_client/image_tools.py:48-55:
    one ratio, the larger of the two float quotients; each side divided by it and truncated by int(); each offset
    half the leftover, truncated by int() (after a float division) and floored at 0. For LIBERO's 256 -> 224 the
    ratio is 256/224 = 1.1428571428571428 and 256 / ratio == 224.0 exactly, so no padding.
    """
    ratio = max(cur_w / width, cur_h / height)
    new_h = int(cur_h / ratio)
    new_w = int(cur_w / ratio)
    top = max(0, int((height - new_h) / 2))
    left = max(0, int((width - new_w) / 2))
    return new_w, new_h, left, top


def _resize_one(image: Image.Image, height: int, width: int, method: int) -> Image.Image:
    # image_tools.py:44-46: PIL's size is (width, height); an image already at the target size is returned as is.
    cur_w, cur_h = image.size
    if (cur_w, cur_h) == (width, height):
        return image
    new_w, new_h, left, top = _pad_geometry(cur_w, cur_h, width, height)
    # image_tools.py:51: PIL Image.resize, resample=method (Image.BILINEAR by default, :15), no box, no reducing_gap.
    shrunk = image.resize((new_w, new_h), resample=method)
    # image_tools.py:53-56: a new image of the same mode filled with 0, the resized one pasted at (left, top).
    canvas = Image.new(shrunk.mode, (width, height), 0)
    canvas.paste(shrunk, (left, top))
    return canvas


def resize_with_pad(images: np.ndarray, height: int, width: int, method: int = Image.BILINEAR) -> np.ndarray:
    """openpi_client.image_tools.resize_with_pad restated: PIL bilinear, aspect kept, zero padding.

    Physical-Intelligence/openpi@15a9616 packages/openpi-client/src/openpi_client/image_tools.py:15-35.
    :28-29: when the last-but-one two axes already equal (height, width) the very array passed in comes back
    (no PIL round trip, no copy). Otherwise :33-35: flattened to a batch of (H, W, C), each image through
    Image.fromarray (uint8 (H, W, 3) -> mode "RGB"), resized and padded, np.stack of the PIL images (uint8), reshaped
    back to the leading axes.
    """
    if images.shape[-3:-1] == (height, width):
        return images
    lead = images.shape[:-3]
    batch = images.reshape(-1, *images.shape[-3:])
    out = np.stack([np.asarray(_resize_one(Image.fromarray(one), height, width, method)) for one in batch])
    return out.reshape(*lead, *out.shape[-3:])


def convert_to_uint8(img: np.ndarray) -> np.ndarray:
    """image_tools.convert_to_uint8: only a floating image changes, (255 * img) truncated by astype(uint8).

    Physical-Intelligence/openpi@15a9616 packages/openpi-client/src/openpi_client/image_tools.py:5-12.
    LIBERO renders uint8, so on upstream's path this returns its argument unchanged.
    """
    if np.issubdtype(img.dtype, np.floating):
        return (255 * img).astype(np.uint8)
    return img


def image(raw: np.ndarray, resize_size: int = RESIZE_SIZE) -> np.ndarray:
    """One camera image as upstream sends it: rotated 180 degrees, resized with padding, uint8.

    Physical-Intelligence/openpi@15a9616 examples/libero/main.py:115-122: [::-1, ::-1] (both the row and the column
    axis reversed, i.e. a 180-degree rotation, not only a vertical flip), np.ascontiguousarray, then
    resize_with_pad(img, resize_size, resize_size) and convert_to_uint8. LIBERO at 256x256 -> (224, 224, 3) uint8.
    """
    rotated = np.ascontiguousarray(raw[::-1, ::-1])
    return convert_to_uint8(resize_with_pad(rotated, resize_size, resize_size))


def request(obs: dict, task_description: str, resize_size: int = RESIZE_SIZE) -> dict:
    """The element upstream's LIBERO client passes to `client.infer` for this observation (before msgpack).

    Physical-Intelligence/openpi@15a9616 examples/libero/main.py:130-141, keys in this insertion order:
      "observation/image":       agentview_image, image() above, uint8 (resize_size, resize_size, 3)   (:115,:117)
      "observation/wrist_image": robot0_eye_in_hand_image, same steps, uint8                          (:116,:120)
      "observation/state":       state() above, float64 (8,)                                          (:133-139)
      "prompt":                  str(task_description): LIBERO's task.language as is, no case change,
                                 no strip, no template (:140; task_description = task.language at :191)
    Nothing else is sent: no seed, no unnorm key, no batch axis. The only client option that changes the payload is
    resize_size (Args.resize_size, :28); replan_steps changes only how much of the reply is executed.
    """
    return {
        "observation/image": image(obs["agentview_image"], resize_size),
        "observation/wrist_image": image(obs["robot0_eye_in_hand_image"], resize_size),
        "observation/state": state(obs),
        "prompt": str(task_description),
    }


# ---------------------------------------------------------------------------------------------------------------------
# Reply -> env.step
# ---------------------------------------------------------------------------------------------------------------------


def executed(reply: dict, replan_steps: int = REPLAN_STEPS) -> list:
    """The actions upstream's LIBERO client passes to env.step for this reply, in order, before it asks again.

    `reply` is the reply as openpi_client decodes it (msgpack_numpy: "actions" a read-only np.ndarray of the dtype
    the server packed, here (horizon, 7)). Upstream does no arithmetic on it at all:
      - only reply["actions"] is read (main.py:144); "policy_timing" / "server_timing" are ignored;
      - it asserts len(actions) >= replan_steps (main.py:145-147); a shorter chunk raises AssertionError, which
        the episode loop's `except Exception` logs and ends the episode with (main.py:160-162); raised here;
      - actions[:replan_steps] is iterated row by row into the deque (main.py:148), each row a 1-D view of the
        reply's array, same dtype;
      - each row is popped (main.py:150) and passed as row.tolist() (main.py:153): a list of 7 Python floats, each
        the exact value of the array element (a float32 element widened to double, no rounding), no clip, no
        gripper flip, no binarization, no un-normalization on the client side.
    Fewer of these actions run when the episode ends first: env.step's done (main.py:154-157) or the step budget
    (main.py:104).
    """
    chunk = reply["actions"]
    assert len(chunk) >= replan_steps, (
        f"We want to replan every {replan_steps} steps, but policy only predicts {len(chunk)} steps."
    )
    return [row.tolist() for row in chunk[:replan_steps]]


def query_steps(suite: str = DEFAULT_SUITE, replan_steps: int = REPLAN_STEPS) -> list[int]:
    """The loop counter t (warm-up steps included) at which upstream queries the server, if no episode ends early.

    Physical-Intelligence/openpi@15a9616 examples/libero/main.py:100-158: t starts at 0 after env.reset() and
    env.set_init_state(initial_states[episode_idx]) (:93-97); for t < num_steps_wait the dummy action is stepped
    (:108-111); afterwards a query happens whenever the deque is empty (:127), i.e. at t = num_steps_wait,
    num_steps_wait + replan_steps, ... while t < max_steps + num_steps_wait (:104).
    """
    end = MAX_STEPS[suite] + NUM_STEPS_WAIT
    return list(range(NUM_STEPS_WAIT, end, replan_steps))


# ---------------------------------------------------------------------------------------------------------------------
# The wire (optional): msgpack with numpy arrays as upstream's msgpack_numpy packs them.
# ---------------------------------------------------------------------------------------------------------------------


def _pack_default(obj):
    # Physical-Intelligence/openpi@15a9616 packages/openpi-client/src/openpi_client/msgpack_numpy.py:21-40:
    # dtype kinds V, O, c refused; an ndarray -> {__ndarray__: True, data: tobytes() (C order), dtype: dtype.str
    # (e.g. "|u1", "<f8"), shape}; a numpy scalar -> {__npgeneric__: True, data: item(), dtype: dtype.str}.
    if isinstance(obj, np.ndarray | np.generic) and obj.dtype.kind in "VOc":
        raise ValueError(f"Unsupported dtype: {obj.dtype}")
    if isinstance(obj, np.ndarray):
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
    if isinstance(obj, np.generic):
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    return obj


def _unpack_hook(obj):
    # msgpack_numpy.py:43-50: an ndarray is rebuilt over the received bytes (np.ndarray(buffer=...), read-only);
    # the shape comes back as a list, which np.ndarray accepts.
    if b"__ndarray__" in obj:
        return np.ndarray(buffer=obj[b"data"], dtype=np.dtype(obj[b"dtype"]), shape=obj[b"shape"])
    if b"__npgeneric__" in obj:
        return np.dtype(obj[b"dtype"]).type(obj[b"data"])
    return obj


def encode(element: dict) -> bytes:
    """The bytes upstream's client sends for `element` (ws_client:48-49: msgpack.Packer(default=...).pack).

    Physical-Intelligence/openpi@15a9616 packages/openpi-client/src/openpi_client/msgpack_numpy.py:53 and
    websocket_client_policy.py:25,48. Packer defaults: use_bin_type=True, so str -> msgpack str, bytes -> bin.
    """
    import msgpack

    return msgpack.Packer(default=_pack_default).pack(element)


def decode(payload: bytes) -> dict:
    """A reply's bytes as upstream's client decodes them (websocket_client_policy.py:50-54, msgpack_numpy.py:57).

    A str frame is the server's traceback: upstream raises RuntimeError (websocket_client_policy.py:51-53).
    """
    if isinstance(payload, str):
        raise RuntimeError(f"Error in inference server:\n{payload}")
    import msgpack

    return msgpack.unpackb(payload, object_hook=_unpack_hook)
