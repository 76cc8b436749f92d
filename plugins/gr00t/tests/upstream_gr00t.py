"""GR00T N1.7's own LIBERO client, restated from NVIDIA/Isaac-GR00T's source (issue #43).

Written by a separate reader from upstream's files only (never from conflictbench's plugin), so a test can
compare the plugin with it bit for bit. Pure functions, numpy and math only.

Where upstream's client lives: ``gr00t/eval/rollout_policy.py`` drives a gymnasium 0.29.1 vector env
(``SyncVectorEnv`` for one env, ``AsyncVectorEnv`` for more) of ``MultiStepWrapper(LiberoEnv)``, and sends the
vector env's batched observation as it is to NVIDIA's ZeroMQ ``PolicyClient``; the server's reply is handed as
it is back to the vector env's ``step``. Everything between LIBERO and the wire therefore happens in
``gr00t/eval/sim/LIBERO/libero_env.py`` (key layout, image flip, axis-angle, gripper mapping),
``gr00t/eval/sim/wrapper/multistep_wrapper.py`` (history stacking, chunk slicing, step budget) and gymnasium
0.29.1's vector utilities (batching into buffers of the observation space's dtype: that is where the state
becomes float32; iterating the reply per env). The model's own pre/post-processing (resize, normalization,
un-normalization) is on the server, not in the client.

Pinned: the ``n1.7-release`` tag, NVIDIA/Isaac-GR00T@23ace64f17aa5015259b8609d371eb61a357c776 ("GR00T N1.7
Release", 2026-04-17). Read from a full clone of NVIDIA's repository (fork squirel2000/Isaac-GR00T_n1d7, whose
refs carry NVIDIA's tags and branches; its commit ade260e's ``gr00t/policy/server_client.py`` has the same
9155 characters as the copy the search index stores for NVIDIA/Isaac-GR00T@ade260e). The index itself holds no
copy of ``gr00t/eval/sim/LIBERO/libero_env.py`` for NVIDIA/Isaac-GR00T. Main at
NVIDIA/Isaac-GR00T@626af89d3e914ec92eab5323e23b9ed44a7b26c8 (2026-05-26) was checked too: everything this
module restates is the same there (see ``REVISIONS``); only the wire encoding changed.

Upstream's LIBERO environment pins ``numpy==1.26.4`` and ``gymnasium==0.29.1``
(NVIDIA/Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/setup_libero.sh:24-25); the dtype of every intermediate
below follows numpy 1.26's promotion rules whatever numpy runs this module.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

SOURCE = {
    "repository": "NVIDIA/Isaac-GR00T",
    "commit": "23ace64f17aa5015259b8609d371eb61a357c776",
    "files": [
        "examples/LIBERO/README.md",
        "gr00t/eval/rollout_policy.py",
        "gr00t/eval/sim/LIBERO/libero_env.py",
        "gr00t/eval/sim/LIBERO/setup_libero.sh",
        "gr00t/eval/sim/wrapper/multistep_wrapper.py",
        "gr00t/policy/server_client.py",
        "gr00t/policy/policy.py",
        "gr00t/policy/gr00t_policy.py",
        "gr00t/eval/run_gr00t_server.py",
        "gr00t/configs/data/embodiment_configs.py",
    ],
    # Not in NVIDIA's repository, but on the path: gymnasium 0.29.1 (the wheel on PyPI) batches the
    # observation and splits the reply; LIBERO's BDDLBaseDomain.step makes ``done`` the task's success.
    "third_party": [
        "gymnasium==0.29.1 gymnasium/vector/sync_vector_env.py, async_vector_env.py",
        "gymnasium==0.29.1 gymnasium/vector/utils/numpy_utils.py, spaces.py",
        "gymnasium==0.29.1 gymnasium/spaces/box.py, dict.py",
        "Lifelong-Robot-Learning/LIBERO libero/libero/envs/bddl_base_domain.py (step: done = _check_success())",
    ],
}

# Revisions checked besides the pin, and what differs on this path.
REVISIONS = {
    "626af89d3e914ec92eab5323e23b9ed44a7b26c8": (
        "main 2026-05-26: request and executed actions unchanged (multistep_wrapper.py, gr00t_policy.py, "
        "run_gr00t_server.py byte-identical; libero_env.py adds ignore_done=True to OffScreenRenderEnv "
        "(:102-109) and seeds the env on reset(seed) (:161-164); rollout_policy.py adds --seed). The wire "
        "encoding changed at 3df8b38 (2026-05-07): MsgSerializer now packs arrays with msgpack_numpy "
        "({'nd','type','kind','shape','data'}) instead of np.save bytes under '__ndarray_class__'/'as_npy' "
        "(server_client.py:31-112 at 626af89 vs :30-60 at 23ace64); the two revisions cannot talk to each other."
    ),
    "559269d2931a7a5fe18fa9e520aba1a23d1504bc": (
        "an N1.6 README (examples/LIBERO/README.md): same client command (--n_action_steps 8, "
        "--max_episode_steps=720, --n_envs 5), server with --embodiment-tag NEW_EMBODIMENT"
    ),
}

# ---- Episode constants -----------------------------------------------------------------------------------

# No no-op warm-up: LiberoEnv.reset returns the first observation of OffScreenRenderEnv.reset() at once.
# NVIDIA/Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/libero_env.py:158-162
NUM_STEPS_WAIT = 0
# Nor LIBERO's fixed benchmark initial states: reset() is OffScreenRenderEnv.reset(), never set_init_state.
# NVIDIA/Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/libero_env.py:159
USES_BENCHMARK_INIT_STATES = False

# Environment steps per episode, the same in every suite: the README's command passes 720
# (NVIDIA/Isaac-GR00T@23ace64 examples/LIBERO/README.md:142); rollout_policy's CLI default is 504
# (gr00t/eval/rollout_policy.py:461). MultiStepWrapper counts every env.step (multistep_wrapper.py:286-290).
MAX_EPISODE_STEPS = 720
MAX_EPISODE_STEPS_BY_SUITE = {
    "libero_spatial": 720,
    "libero_object": 720,
    "libero_goal": 720,
    "libero_10": 720,
    "libero_90": 720,
}
MAX_EPISODE_STEPS_CLI_DEFAULT = 504

# Actions of each chunk executed before asking again: README --n-action-steps 8
# (NVIDIA/Isaac-GR00T@23ace64 examples/LIBERO/README.md:144; rollout_policy.py:482 default 8).
N_ACTION_STEPS = 8
# The chunk the server answers: 16 steps for the libero_sim embodiment
# (NVIDIA/Isaac-GR00T@23ace64 gr00t/configs/data/embodiment_configs.py:154-157); the checkpoint's own
# processor config decides what a served model returns, and the client only reads the first N_ACTION_STEPS.
ACTION_HORIZON = 16
# README: 5 parallel envs, 10 episodes (examples/LIBERO/README.md:139,145).
N_ENVS = 5
N_EPISODES = 10
# The episode ends after a chunk in which any step succeeded (rollout_policy.py:433,
# multistep_wrapper.py:321-323); inside the chunk LIBERO's done (= success) stops it at once
# (multistep_wrapper.py:275-277).
TERMINATE_ON_SUCCESS = True
# Rendered size, sent without resizing (libero_env.py:102-106).
CAMERA_HEIGHT = CAMERA_WIDTH = 256

# ---- Keys ----------------------------------------------------------------------------------------------

LANGUAGE_KEY = "annotation.human.action.task_description"
VIDEO_KEYS = ("video.image", "video.wrist_image")
STATE_KEYS = ("state.x", "state.y", "state.z", "state.roll", "state.pitch", "state.yaw", "state.gripper")
# The order LiberoEnv.step concatenates them in (libero_env.py:165-176).
ACTION_KEYS = ("action.x", "action.y", "action.z", "action.roll", "action.pitch", "action.yaw", "action.gripper")
# gymnasium's spaces.Dict sorts a plain dict's keys (gymnasium 0.29.1 spaces/dict.py:70-74), and the vector
# env's batched observation is an OrderedDict in that order (vector/utils/numpy_utils.py:70-77): the order
# the observation is packed in.
OBSERVATION_KEYS = tuple(sorted((LANGUAGE_KEY, *VIDEO_KEYS, *STATE_KEYS)))


def quat2axisangle(quat: np.ndarray) -> np.ndarray:
    """robosuite's quaternion (x, y, z, w) to axis-angle, as upstream's copy computes it, in float64.

    NVIDIA/Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/libero_env.py:41-65. Upstream clips ``quat[3]`` in
    place in LIBERO's own observation array; here a copy is clipped, so the caller's ``obs`` is untouched.
    """
    q = np.array(quat, copy=True)
    # :55-58 clip w to [-1, 1]
    if q[3] > 1.0:
        q[3] = 1.0
    elif q[3] < -1.0:
        q[3] = -1.0
    # :60 den = sqrt(1 - w*w), numpy float64
    den = np.sqrt(1.0 - q[3] * q[3])
    # :61-63 math.isclose(den, 0.0) (default tolerances: true only for den == 0) -> float64 zeros
    if math.isclose(den, 0.0):
        return np.zeros(3)
    # :65 evaluated left to right: ((xyz * 2.0) * acos(w)) / den
    return (q[:3] * 2.0 * math.acos(q[3])) / den


def _check_settings(settings: dict[str, Any], allowed: tuple[str, ...]) -> None:
    unknown = sorted(set(settings) - set(allowed))
    if unknown:
        raise TypeError(f"settings upstream's GR00T LIBERO client does not have: {unknown}")


def request(obs: dict, task_description: str, **settings: Any) -> dict:
    """The observation upstream's LIBERO client passes to ``PolicyClient.get_action`` for one env (B = 1).

    No setting changes this payload (no resize, no prompt formatting, no statistics on the client); with
    several envs each row is built the same way and stacked on axis 0, the language a tuple of B strings.

    Steps, in upstream's order:

    1. ``LiberoEnv._process_observation`` (NVIDIA/Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/libero_env.py:140-156):
       both cameras turned 180 degrees (``[::-1, ::-1]``, :145-146), uint8 as rendered at 256 x 256;
       ``state.x/y/z`` = ``[eef_pos[i]]`` (lists of one float64, :147-149); ``state.roll/pitch/yaw`` = the
       three axis-angle components of ``quat2axisangle(eef_quat)`` (float64, :142,150-152; names aside,
       not Euler angles); ``state.gripper`` = ``robot0_gripper_qpos`` (2,) float64 (:143,153); the task text
       unchanged, LIBERO's ``task.language`` (:154, registered at :197-208).
    2. ``MultiStepWrapper._get_obs`` with delta indices ``[0]`` (rollout_policy.py:84-85,182-189;
       multistep_wrapper.py:327-369): video and state ``np.stack([latest], axis=0)``: (1, 256, 256, 3) uint8,
       (1, 1) / (1, 2) float64 (:346-357); the annotation the latest string (:358-359).
    3. The vector env batches into buffers made from the observation space (gymnasium 0.29.1
       vector/utils/numpy_utils.py:119-126 ``np.zeros(shape, dtype=space.dtype)``, :54-59
       ``np.stack(items, axis=0, out=buffer)``): the state Boxes have gymnasium's default dtype float32
       (libero_env.py:115-121 give none; gymnasium 0.29.1 spaces/box.py:60), so the float64 state is cast
       to float32 here, round to nearest; video stays uint8 (libero_env.py:111-114). The Text space is
       batched as ``tuple(items)`` (numpy_utils.py:80-82). Shapes: video (1, 1, 256, 256, 3), state
       (1, 1, 1) and (1, 1, 2), keys in sorted order (``OBSERVATION_KEYS``).
    4. ``policy.get_action(observations)`` (rollout_policy.py:280) on a ``PolicyClient`` (:385, strict=False:
       no check, server_client.py:179; policy.py:100-102) sends it unchanged as ``data.observation``,
       ``data.options`` None (server_client.py:249-254): see ``envelope``.
    """
    _check_settings(settings, ())
    # libero_env.py:141-143
    xyz = obs["robot0_eef_pos"]
    rpy = quat2axisangle(obs["robot0_eef_quat"])
    gripper = obs["robot0_gripper_qpos"]

    def image(key: str) -> np.ndarray:
        # libero_env.py:145-146 flip both axes; multistep_wrapper.py:346-348 stack the one frame (T = 1);
        # vector env: stack into a uint8 buffer (B = 1)
        frame = np.asarray(obs[key])[::-1, ::-1]
        out = np.zeros((1, 1, *frame.shape), dtype=np.uint8)
        np.stack([np.stack([frame], axis=0)], axis=0, out=out)
        return out

    def state(values: list) -> np.ndarray:
        # multistep_wrapper.py:356-357 np.stack([[...float64]], axis=0) -> (1, D) float64;
        # vector env: np.stack into the float32 buffer of the Box (casting 'same_kind', round to nearest)
        per_env = np.stack([values], axis=0)
        out = np.zeros((1, *per_env.shape), dtype=np.float32)
        np.stack([per_env], axis=0, out=out)
        return out

    flat = {
        "video.image": image("agentview_image"),
        "video.wrist_image": image("robot0_eye_in_hand_image"),
        "state.x": state([xyz[0]]),
        "state.y": state([xyz[1]]),
        "state.z": state([xyz[2]]),
        "state.roll": state([rpy[0]]),
        "state.pitch": state([rpy[1]]),
        "state.yaw": state([rpy[2]]),
        "state.gripper": state(gripper),
        # numpy_utils.py:80-82: a Text space is batched as a tuple of the envs' strings
        LANGUAGE_KEY: (task_description,),
    }
    return {key: flat[key] for key in OBSERVATION_KEYS}


def envelope(observation: dict, options: dict | None = None, api_token: str | None = None) -> dict:
    """The whole request ``PolicyClient.call_endpoint('get_action', ...)`` packs for ``observation``.

    NVIDIA/Isaac-GR00T@23ace64 gr00t/policy/server_client.py:221-225,252-254: ``{"endpoint": "get_action",
    "data": {"observation": ..., "options": None}}``, ``"api_token"`` only when the client has one (the
    README's client has none: rollout_policy.py:385). Wire encoding (not restated here): msgpack with each
    ndarray as ``{"__ndarray_class__": True, "as_npy": np.save bytes}`` at 23ace64 (server_client.py:30-60),
    msgpack_numpy at main 626af89 (server_client.py:31-112).
    """
    message: dict = {"endpoint": "get_action", "data": {"observation": observation, "options": options}}
    if api_token:
        message["api_token"] = api_token
    return message


def _float_after_numpy1_promotion(dtype: np.dtype) -> np.dtype:
    # Upstream's LIBERO env runs numpy 1.26.4 (setup_libero.sh:25): there a 0-d array combined with a
    # Python float promotes as two scalars, so a float32 gripper value becomes float64 for the arithmetic
    # (numpy 2 would keep float32; the executed values are the same either way, the dtype is followed here).
    return np.promote_types(dtype, np.float64)


def _libero_step_action(act: dict) -> np.ndarray:
    """``LiberoEnv.step``'s arithmetic on one step's action dict; returns what it passes to LIBERO's step.

    NVIDIA/Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/libero_env.py:164-179.
    """
    # :165-176 concatenate the seven (1,) arrays in x, y, z, roll, pitch, yaw, gripper order -> (7,), in
    # the reply's dtype (float32 from NVIDIA's server, gr00t_policy.py:419-422)
    vector = np.concatenate([act[key] for key in ACTION_KEYS], axis=0)
    # :177 normalize_gripper_action(binarize=True) (:68-85):
    #   :78-79 g <- 2 * (g - 0.0) / (1.0 - 0.0) - 1, computed in float64 (numpy 1.26), stored in the
    #   vector's dtype
    wide = _float_after_numpy1_promotion(vector.dtype)
    g = vector[..., -1].astype(wide)
    vector[..., -1] = 2 * (g - 0.0) / (1.0 - 0.0) - 1
    #   :81-83 g <- np.sign(g) (same dtype as the vector): -1, +1, or 0 exactly at g == 0.5 (nan stays nan)
    vector[..., -1] = np.sign(vector[..., -1])
    # :178 invert_gripper_action (:88-95): g <- g * -1.0 (float64 under numpy 1.26, stored back); the
    # 0 of g == 0.5 becomes -0.0
    vector[..., -1] = vector[..., -1].astype(_float_after_numpy1_promotion(vector.dtype)) * -1.0
    # :179 self._env.step(action_vector): the ndarray itself (not a list), shape (7,), no clipping on the
    # client (robosuite's controller clips its input itself)
    return vector


def executed(
    reply: Any,
    n_action_steps: int = N_ACTION_STEPS,
    *,
    env_index: int = 0,
    steps_taken: int = 0,
    max_episode_steps: int = MAX_EPISODE_STEPS,
    done_at: int | None = None,
    **settings: Any,
) -> list[np.ndarray]:
    """The actions upstream's LIBERO client passes to LIBERO's ``env.step`` for one reply, in order.

    ``reply``: the decoded ``get_action`` answer, ``(action, info)`` as ``PolicyClient._get_action`` returns
    it (server_client.py:255) or just the action dict: ``"action.x" ... "action.gripper"`` each (B, T, 1)
    float32 (gr00t_policy.py:419-422, 682). Each returned item is exactly what upstream hands to
    ``OffScreenRenderEnv.step``: a (7,) ndarray in the reply's dtype (float32), positions and rotations
    the reply's values bit for bit, the gripper -sign(2g - 1) (+1 closes in LIBERO; g is the dataset's
    [0, 1] with 1 = open).

    Stateless between queries (no queue, no ensembling): each reply's first ``n_action_steps`` actions are
    executed open-loop, then the client sends the new observation. The chunk stops early:
    - after the step at index ``done_at`` when LIBERO reports ``done`` (its success, bddl_base_domain.py
      ``done = self._check_success()``) there (multistep_wrapper.py:275-277);
    - when the episode's step budget is spent: ``steps_taken`` env steps before this reply, at most
      ``max_episode_steps`` in all (multistep_wrapper.py:286-291, then :275-277).

    Steps: rollout_policy.py:280-281 ``env.step(actions)`` with the reply unchanged; gymnasium 0.29.1
    ``iterate(action_space, actions)`` gives env ``env_index`` the row ``reply[key][env_index]`` of each key
    the action space has (vector/utils/spaces.py:170-175,197-206; sync_vector_env.py:131-133,
    async_vector_env.py:285); ``MultiStepWrapper.step`` takes ``value[step, :]`` for step 0..n-1
    (multistep_wrapper.py:271-278); ``LiberoEnv.step`` maps it (see ``_libero_step_action``).
    """
    _check_settings(settings, ())
    action = reply[0] if isinstance(reply, (tuple, list)) else reply
    rows = {key: action[key][env_index] for key in sorted(ACTION_KEYS)}
    out: list[np.ndarray] = []
    rewards = steps_taken
    done = False
    for step in range(n_action_steps):
        # multistep_wrapper.py:272-274 this step's (1,) slice of every key
        act = {key: value[step, :] for key, value in rows.items()}
        # :275-277 stop once the previous step ended the episode
        if done:
            break
        out.append(_libero_step_action(act))
        rewards += 1
        done = done_at is not None and step >= done_at
        # :286-290 truncation once the episode has taken max_episode_steps steps
        if max_episode_steps is not None and rewards >= max_episode_steps:
            done = True
    return out
