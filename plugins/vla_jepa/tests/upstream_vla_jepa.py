"""VLA-JEPA's own LIBERO client, restated from upstream's source only (issue #43).

Written by a separate reader from ginwind/VLA-JEPA at the commit in ``SOURCE``, without reading
conflictbench's plugin: it is the reference the plugin's processing is compared against, bit for bit.

Upstream's client is two files: ``examples/LIBERO/eval_libero.py`` (the episode loop, the
observation's preprocessing, the final cast before ``env.step``) and
``examples/LIBERO/model2libero_interface.py`` (class ``M1Inference``: resize, payload, query
schedule, un-normalization). It talks msgpack over a websocket to
``deployment/model_server/server_policy.py``.

State across queries: the client keeps the last un-normalized chunk (``self.raw_actions``) and
indexes it by the policy step; a reply is used for exactly ``chunk_size`` consecutive steps and is
then replaced whole. No temporal ensembling runs (an ``AdaptiveEnsembler`` is constructed but
``M1Inference.step`` never calls it), so pure functions suffice: ``executed(reply)`` returns the
``chunk_size`` actions one reply produces, in order.

Every line number below is at the pinned commit. Citation form: ``owner/name@<7 hex> path:LINE``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

SOURCE = {
    "repository": "ginwind/VLA-JEPA",
    "commit": "ec8c70f6e155e2377bbd4d787004c14179c00c7c",
    "files": [
        "examples/LIBERO/eval_libero.py",
        "examples/LIBERO/model2libero_interface.py",
        "examples/LIBERO/eval_libero.sh",
        "deployment/model_server/server_policy.py",
        "deployment/model_server/tools/websocket_policy_client.py",
        "deployment/model_server/tools/websocket_policy_server.py",
        "deployment/model_server/tools/msgpack_numpy.py",
        "deployment/model_server/tools/image_tools.py",
        "starVLA/model/framework/VLA_JEPA.py",
        "starVLA/model/tools.py",
    ],
}

# ---------------------------------------------------------------------------------------------
# Episode constants
# ---------------------------------------------------------------------------------------------

# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:23 (a list of Python floats; -1.0 = open)
LIBERO_DUMMY_ACTION = [0.0] * 6 + [-1.0]
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:24, used at :125 (camera height and width)
LIBERO_ENV_RESOLUTION = 256
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:48 (warm-up: env.step(LIBERO_DUMMY_ACTION), :154-157)
NUM_STEPS_WAIT = 10
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:49
NUM_TRIALS_PER_TASK = 50
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:64 (np.random.seed at :79, env.seed at :287)
SEED = 7
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:47
DEFAULT_TASK_SUITE = "libero_goal"
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:42 -> model2libero_interface.py:43,168 (cv2 dsize = (W, H))
RESIZE_SIZE = (224, 224)
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:70 (a string; state is sent only when == "true", :194-195)
WITH_STATE = "true"

# Policy steps per episode (the loop runs while t < max_steps + NUM_STEPS_WAIT, :150, so the
# policy acts at most max_steps times after the warm-up).
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:94-105
MAX_STEPS = {
    "libero_spatial": 250,
    "libero_object": 280,
    "libero_goal": 300,
    "libero_10": 520,
    "libero_mix": 520,
    "libero_90": 400,
}

# Every revision of eval_libero.py (git log -p -- examples/LIBERO/eval_libero.py): only the
# libero_spatial budget changed; NUM_STEPS_WAIT (10) and the dummy action never changed.
MAX_STEPS_BY_REVISION = {
    # ginwind/VLA-JEPA@6e4846c examples/LIBERO/eval_libero.py:94-105 (file added)
    "6e4846cc4fccbe33ba32172da6eb34699875a39c": {**MAX_STEPS, "libero_spatial": 400},
    # ginwind/VLA-JEPA@c3d2fde examples/LIBERO/eval_libero.py:95
    "c3d2fdead919409d93e148ae04ed25995fa09f7f": {**MAX_STEPS, "libero_spatial": 200},
    # ginwind/VLA-JEPA@29cab99 examples/LIBERO/eval_libero.py:95 (unchanged through ec8c70f)
    "29cab994c6906310429c8329ed5abce4e843cc77": dict(MAX_STEPS),
}
NUM_STEPS_WAIT_BY_REVISION = dict.fromkeys(MAX_STEPS_BY_REVISION, NUM_STEPS_WAIT)

# Model options M1Inference puts in every payload (eval_libero.py:107-112 passes none of them).
# ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:22,28,29
UNNORM_KEY = None
USE_DDIM = True
NUM_DDIM_STEPS = 10


# ---------------------------------------------------------------------------------------------
# In: LIBERO observation -> payload
# ---------------------------------------------------------------------------------------------


def quat2axisangle(quat: np.ndarray) -> np.ndarray:
    """ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:293-308 (float64 in, float64 out).

    Upstream clips quat[3] in place in the observation's own array (:298-301); this copy leaves
    the caller's array alone, the values are the same.
    """
    q = np.array(quat, copy=True)
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:298-301
    if q[3] > 1.0:
        q[3] = 1.0
    elif q[3] < -1.0:
        q[3] = -1.0
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:303 (np.float64 scalar)
    den = np.sqrt(1.0 - q[3] * q[3])
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:304-306 (abs_tol 0: only den == 0 exactly)
    if math.isclose(den, 0.0):
        return np.zeros(3)
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:308, evaluated left to right:
    # ((q[:3] * 2.0) * math.acos(q[3])) / den
    return (q[:3] * 2.0 * math.acos(q[3])) / den


def state(obs: dict) -> np.ndarray:
    """(8,) float64: eef_pos (3), axis-angle (3), gripper_qpos (2).

    ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:168-174
    """
    return np.concatenate(
        (
            obs["robot0_eef_pos"],
            quat2axisangle(obs["robot0_eef_quat"]),
            obs["robot0_gripper_qpos"],
        )
    )


def image(rendered: np.ndarray, resize_size=RESIZE_SIZE) -> np.ndarray:
    """(H, W, 3) uint8 as rendered -> (224, 224, 3) uint8, rotated 180 degrees, cv2 INTER_AREA.

    No JPEG anywhere; no padding; the resize distorts nothing here (256x256 -> 224x224).
    """
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:160-163 ([::-1, ::-1], made contiguous)
    flipped = np.ascontiguousarray(rendered[::-1, ::-1])
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:167-169
    # (cv.resize(image, tuple(self.image_size), interpolation=cv.INTER_AREA); dsize is (W, H))
    return cv2.resize(flipped, tuple(resize_size), interpolation=cv2.INTER_AREA)


def request(
    obs: dict,
    task_description: str,
    *,
    resize_size=RESIZE_SIZE,
    unnorm_key=UNNORM_KEY,
    with_state: str = WITH_STATE,
    use_ddim: bool = USE_DDIM,
    num_ddim_steps: int = NUM_DDIM_STEPS,
    **_ignored,
) -> dict:
    """The payload (``vla_input``) upstream's client sends for ``obs``, before msgpack.

    Key order is upstream's insertion order (msgpack keeps it on the wire).
    ``client.infer`` wraps it as ``{"payload": vla_input, "type": "infer"}`` (see ``infer_message``).
    ``task_description`` is LIBERO's ``task.language`` verbatim (eval_libero.py:275, :133 ->
    model2libero_interface.py:70,106): no case change, no strip, no prompt template on the client.
    """
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:189 -> model2libero_interface.py:103
    images = [image(obs["agentview_image"], resize_size), image(obs["robot0_eye_in_hand_image"], resize_size)]
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:104-111
    vla_input = {
        "batch_images": [images],
        "instructions": [task_description],
        "unnorm_key": unnorm_key,
        "do_sample": False,
        "use_ddim": use_ddim,
        "num_ddim_steps": num_ddim_steps,
    }
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:183,194-195 (np.expand_dims -> (1, 8) float64)
    # and model2libero_interface.py:113-114 (wrapped in a list: [array (1, 8)])
    if with_state == "true":
        vla_input["state"] = [np.expand_dims(state(obs), axis=0)]
    return vla_input


def infer_message(payload: dict) -> dict:
    """ginwind/VLA-JEPA@ec8c70f deployment/model_server/tools/websocket_policy_client.py:72-75"""
    return {"payload": payload, "type": "infer"}


def pack(message) -> bytes:
    """The wire bytes: msgpack with upstream's numpy hook.

    ginwind/VLA-JEPA@ec8c70f deployment/model_server/tools/msgpack_numpy.py:21-40,53
    (ndarray -> {b"__ndarray__": True, b"data": tobytes(), b"dtype": dtype.str, b"shape": shape};
    numpy scalar -> {b"__npgeneric__": True, b"data": item(), b"dtype": dtype.str}); packed with
    ``msgpack.Packer(default=...)`` defaults (websocket_policy_client.py:26,76).
    """
    import msgpack

    def default(obj):
        if isinstance(obj, (np.ndarray, np.generic)) and obj.dtype.kind in ("V", "O", "c"):
            raise ValueError(f"Unsupported dtype: {obj.dtype}")
        if isinstance(obj, np.ndarray):
            return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
        if isinstance(obj, np.generic):
            return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
        return obj

    return msgpack.Packer(default=default).pack(message)


def unpack(data: bytes):
    """ginwind/VLA-JEPA@ec8c70f deployment/model_server/tools/msgpack_numpy.py:43-50,57.

    Arrays come back as read-only ``np.ndarray(buffer=bytes, dtype, shape)``.
    """
    import msgpack

    def hook(obj):
        if b"__ndarray__" in obj:
            return np.ndarray(buffer=obj[b"data"], dtype=np.dtype(obj[b"dtype"]), shape=obj[b"shape"])
        if b"__npgeneric__" in obj:
            return np.dtype(obj[b"dtype"]).type(obj[b"data"])
        return obj

    return msgpack.unpackb(data, object_hook=hook)


# ---------------------------------------------------------------------------------------------
# Out: reply -> env.step
# ---------------------------------------------------------------------------------------------


def check_unnorm_key(norm_stats: dict, unnorm_key):
    """ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:204-221.

    With upstream's LIBERO default (None) the statistics must hold exactly one key.
    """
    if unnorm_key is None:
        assert len(norm_stats) == 1, f"unnorm_key needed, one of {list(norm_stats)}"
        unnorm_key = next(iter(norm_stats.keys()))
    assert unnorm_key in norm_stats, f"unnorm_key {unnorm_key!r} not in {list(norm_stats)}"
    return unnorm_key


def action_stats(dataset_statistics: dict, unnorm_key=UNNORM_KEY) -> dict:
    """ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:150-158
    (json.load of dataset_statistics.json: starVLA/model/tools.py:190-191, so floats are Python floats)."""
    return dataset_statistics[check_unnorm_key(dataset_statistics, unnorm_key)]["action"]


def chunk_size_from_config(config: dict) -> int:
    """ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:161-164
    (config.yaml through OmegaConf.to_container(resolve=True): starVLA/model/tools.py:183-184)."""
    return config["framework"]["action_model"]["future_action_window_size"] + 1


def unnormalize_actions(normalized_actions: np.ndarray, stats: dict) -> np.ndarray:
    """(chunk, D) model output -> (chunk, D) float64 (for a float32 reply and JSON stats).

    ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:136-147. Dtypes:
    clip, binarize and ``0.5 * (x + 1)`` stay in the reply's dtype (float32); the product with
    ``(max - min)`` (float64 from JSON) promotes to float64; ``+ min`` is float64; ``np.where``
    with the mask yields float64 (masked-out dims: the clipped float32 value, widened exactly).
    """
    # :137 (JSON list of bools when present; starVLA writes False for gripper dims)
    mask = stats.get("mask", np.ones_like(stats["min"], dtype=bool))
    # :138 (np.array of a JSON float list -> float64)
    action_high, action_low = np.array(stats["max"]), np.array(stats["min"])
    # :139 (new array, reply dtype kept; the reply's read-only buffer is not touched)
    normalized_actions = np.clip(normalized_actions, -1, 1)
    # :140 (int64 0/1 written into the float32 column -> 0.0 / 1.0; NaN < 0.5 is False -> 1)
    normalized_actions[:, 6] = np.where(normalized_actions[:, 6] < 0.5, 0, 1)
    # :141-145
    return np.where(
        mask,
        0.5 * (normalized_actions + 1) * (action_high - action_low) + action_low,
        normalized_actions,
    )


def binarize_gripper_open(open_val) -> np.ndarray:
    """ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:25-29: > 0.5 -> -1.0, else +1.0, (1,) float32."""
    arr = np.asarray(open_val, dtype=np.float32).reshape(-1)
    v = float(arr[0])
    bin_val = 1.0 - 2.0 * (v > 0.5)
    return np.asarray([bin_val], dtype=np.float32)


def step_action(raw_actions: np.ndarray, k: int, chunk_size: int) -> np.ndarray:
    """The (7,) float32 array upstream builds for policy step ``k`` (its ``delta_action``)."""
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:125 (row, then [None] -> (1, D))
    row = raw_actions[k % chunk_size][None]
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:127-131 (np.array copies, float64)
    raw_action = {
        "world_vector": np.array(row[0, :3]),
        "rotation_delta": np.array(row[0, 3:6]),
        "open_gripper": np.array(row[0, 6:7]),
    }
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:207-209 (float64 -> float32, round to nearest)
    world_vector_delta = np.asarray(raw_action.get("world_vector"), dtype=np.float32).reshape(-1)
    rotation_delta = np.asarray(raw_action.get("rotation_delta"), dtype=np.float32).reshape(-1)
    open_gripper = np.asarray(raw_action.get("open_gripper"), dtype=np.float32).reshape(-1)
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:210 (threshold on the float32 value)
    gripper = binarize_gripper_open(open_gripper)
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:212-219
    if not (world_vector_delta.size == 3 and rotation_delta.size == 3 and open_gripper.size == 1):
        raise ValueError("Invalid action sizes")
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:221 -> (7,) float32
    return np.concatenate([world_vector_delta, rotation_delta, gripper], axis=0)


def _normalized_actions(reply):
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:121-122
    # (reply = the decoded response dict {"status", "ok", "type", "request_id", "data": {...}},
    # websocket_policy_server.py:124-130; data = predict_action's dict, VLA_JEPA.py:336-337).
    # A bare (B, chunk, D) array is accepted as data["normalized_actions"] itself.
    if isinstance(reply, dict):
        return reply["data"]["normalized_actions"][0]
    return reply[0]


def _resolve_chunk_size(config=None, chunk_size=None) -> int:
    if chunk_size is None:
        if config is None:
            raise TypeError("give config (parsed config.yaml) or chunk_size")
        chunk_size = chunk_size_from_config(config)
    return chunk_size


def executed_arrays(
    reply,
    dataset_statistics: dict,
    unnorm_key=UNNORM_KEY,
    config: dict | None = None,
    chunk_size: int | None = None,
    **_ignored,
) -> list[np.ndarray]:
    """The (7,) float32 arrays upstream passes (as ``.tolist()``) to env.step for one reply, in order.

    Queries happen at policy steps 0, chunk_size, 2*chunk_size, ... counted from 0 after the
    warm-up (model2libero_interface.py:117, eval_libero.py:146,233); each reply serves
    chunk_size steps (fewer if the episode ends: done at :228-231 or the budget at :150).
    """
    n = _resolve_chunk_size(config, chunk_size)
    # ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:123
    raw_actions = unnormalize_actions(_normalized_actions(reply), action_stats(dataset_statistics, unnorm_key))
    return [step_action(raw_actions, k, n) for k in range(n)]


def executed(
    reply,
    dataset_statistics: dict,
    unnorm_key=UNNORM_KEY,
    config: dict | None = None,
    chunk_size: int | None = None,
    **_ignored,
) -> list[list[float]]:
    """What upstream passes to env.step for one reply: lists of 7 Python floats (float32 values).

    ginwind/VLA-JEPA@ec8c70f examples/LIBERO/eval_libero.py:227 (env.step(delta_action.tolist()))
    """
    return [a.tolist() for a in executed_arrays(reply, dataset_statistics, unnorm_key, config, chunk_size)]


def is_query_step(step: int, chunk_size: int) -> bool:
    """ginwind/VLA-JEPA@ec8c70f examples/LIBERO/model2libero_interface.py:117 (step counts policy steps from 0)."""
    return step % chunk_size == 0


def query_steps(task_suite: str, chunk_size: int, max_steps_table: dict = MAX_STEPS) -> list[int]:
    """Policy steps at which a full-length episode queries the server."""
    return [s for s in range(max_steps_table[task_suite]) if is_query_step(s, chunk_size)]
