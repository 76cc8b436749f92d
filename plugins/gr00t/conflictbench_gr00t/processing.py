"""What GR00T's LIBERO client does around the model, step by step (each pinned by ``tests/test_gr00t_processing.py``).

The facts, from Isaac-GR00T's ``gr00t/eval/sim/LIBERO/libero_env.py`` (the environment its LIBERO evaluation
``gr00t/eval/rollout_policy.py`` steps) and ``examples/LIBERO/README.md`` at NVIDIA/Isaac-GR00T@23ace64 (tag
``n1.7-release``), step by step in ``docs/upstream/audit_gr00t.md``:

- **client**: both cameras rotated 180 degrees (LIBERO renders upside down) and sent at the rendered 256 x 256,
  uint8, no resize (``video.image`` = agentview, ``video.wrist_image`` = eye-in-hand); the state split into
  ``state.x, y, z`` (end-effector position), ``state.roll, pitch, yaw`` (the three components of robosuite's
  axis-angle of the end-effector quaternion, despite their names) and ``state.gripper`` (the two finger joint
  positions), float32; the task text under ``annotation.human.action.task_description``; each with the batch
  and time axes the vectorized, multi-step wrapper adds (B = T = 1);
- **server** (the checkpoint's processor): resizing to the model's input, normalizing the state, un-normalizing
  the actions to the dataset's units (gripper in [0, 1], 1 = open); nothing here repeats it;
- **client**, on the reply: ``action.x … action.gripper`` concatenated to 7-D; the gripper mapped to [-1, 1]
  (2g - 1), binarized with ``sign`` (0 stays 0) and inverted (LIBERO: -1 = open, +1 = close); the first 8
  actions of each chunk executed (``--n-action-steps 8``) before asking again;
- **episodes**: no no-op warm-up steps (the wrapper acts from the first step after reset) and at most 720
  steps (``--max-episode-steps 720``) in every suite.
"""

from __future__ import annotations

import numpy as np

from .protocol import ACTION_KEYS, LANGUAGE_KEY, STATE_KEYS, VIDEO_KEYS

#: Actions of each chunk executed before asking again (``--n-action-steps 8``).
ACTION_STEPS = 8
#: Environment steps per episode in GR00T's LIBERO evaluation, the same in every suite.
MAX_EPISODE_STEPS = 720
#: GR00T's wrapper takes no no-op steps after reset.
WARMUP_STEPS = 0


def upright(image: np.ndarray) -> np.ndarray:
    """LIBERO's upside-down render turned the right way up (rows and columns reversed)."""
    return np.ascontiguousarray(image[::-1, ::-1], dtype=np.uint8)


def gr00t_observation(agentview: np.ndarray, wrist: np.ndarray, state: np.ndarray, instruction: str) -> dict:
    """One observation in the sim wrapper's flat layout: B = T = 1 on every array, the text in a list, the keys
    sorted (as upstream's gymnasium batches them).

    ``state`` is LIBERO's 8-D vector (position, axis-angle, two gripper joint positions)."""
    state = np.asarray(state, dtype=np.float64)
    if state.shape != (8,):
        raise ValueError(f"expected LIBERO's 8-D state, got shape {state.shape}")
    observation: dict = {key: upright(image)[None, None] for key, image in zip(VIDEO_KEYS, (agentview, wrist))}
    for index, key in enumerate(STATE_KEYS[:-1]):
        observation[key] = np.asarray(state[index : index + 1], dtype=np.float32)[None, None]
    observation[STATE_KEYS[-1]] = np.asarray(state[6:8], dtype=np.float32)[None, None]
    observation[LANGUAGE_KEY] = [instruction]
    # In upstream's key order, so that the msgpack map is upstream's to the byte: gymnasium's spaces.Dict sorts
    # a plain dict's keys and the vector env batches the observation in that order (gymnasium 0.29.1, which
    # Isaac-GR00T@23ace64 gr00t/eval/sim/LIBERO/setup_libero.sh:24 pins: spaces/dict.py:70-74,
    # vector/utils/numpy_utils.py:70-77). NVIDIA's server looks keys up by name; the order changes no value.
    return {key: observation[key] for key in sorted(observation)}


def env_actions(action: dict, row: int = 0) -> np.ndarray:
    """Row ``row`` of a ``get_action`` reply as LIBERO actions (horizon, 7): concatenated, gripper mapped."""
    missing = [key for key in ACTION_KEYS if key not in action]
    if missing:
        raise ValueError(f"the reply has no {', '.join(missing)} (it has {', '.join(sorted(action)) or 'nothing'})")
    parts = []
    for key in ACTION_KEYS:
        value = np.asarray(action[key], dtype=np.float64)
        if value.ndim != 3 or value.shape[2] != 1 or row >= value.shape[0]:
            raise ValueError(f"{key} has shape {value.shape}, expected (B, T, 1) with B > {row}")
        parts.append(value[row, :, 0])
    horizons = {len(part) for part in parts}
    if len(horizons) != 1 or 0 in horizons:
        raise ValueError(f"the action keys have horizons {sorted(horizons)}, expected one horizon > 0")
    chunk = np.stack(parts, axis=1)
    chunk[:, 6] = -np.sign(2.0 * chunk[:, 6] - 1.0)
    return chunk
