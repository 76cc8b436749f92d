"""The wire between the LIBERO client and the LeRobot server: openpi's framing and codec, our request map.

openpi's framing (conflictbench-serving's websocket server: the packed metadata first, one binary msgpack-numpy
frame per request and per reply, a text frame and close code 1011 for a fatal error). LeRobot's own asynchronous
server pickles, which no peer's bytes may be given to, so it is not used.

A request is what LeRobot's LIBERO env hands ``lerobot-eval``'s rollout at one step, before any of LeRobot's
processing (``LiberoEnv._format_raw_obs``, ``lerobot/envs/libero.py``): both camera images as robosuite renders them
(uint8, upside down, H x W x 3), the robot state as float64 arrays (end-effector position, quaternion (x, y, z, w)
and the controller's orientation matrix, gripper and arm joint positions and velocities), and the task text. Ours
adds the episode it belongs to and its step (the server keeps each episode's action queue), the step's sampling
seed, and the lerobot-eval settings that act on the server (camera names, ``rename_map``, ``n_action_steps``).

The reply is ``{"actions": (1, action_dim)}`` in the dtype the policy returned (float32 for LeRobot's policies):
one action per step, as ``select_action`` gives it.

This module imports neither conflictbench nor torch: both halves use it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench_serving import checkpoints as seeds
from conflictbench_serving.msgpack_numpy import packb as packb  # re-exported: the codec of this protocol
from conflictbench_serving.msgpack_numpy import unpackb as unpackb
from conflictbench_serving.requests import describe, is_noise_seed

#: LeRobot's LIBERO cameras (robosuite's observation names), in the order (agentview, wrist).
CAMERAS = ("agentview_image", "robot0_eye_in_hand_image")
#: The raw robot state ``_format_raw_obs`` reports: request key -> (LeRobot's nested path, shape).
ROBOT_STATE = {
    "robot_state/eef/pos": (("eef", "pos"), (3,)),
    "robot_state/eef/quat": (("eef", "quat"), (4,)),
    "robot_state/eef/mat": (("eef", "mat"), (3, 3)),
    "robot_state/gripper/qpos": (("gripper", "qpos"), (2,)),
    "robot_state/gripper/qvel": (("gripper", "qvel"), (2,)),
    "robot_state/joints/pos": (("joints", "pos"), (7,)),
    "robot_state/joints/vel": (("joints", "vel"), (7,)),
}
PROMPT = "prompt"
EPISODE, STEP = "conflictbench/episode", "conflictbench/step"
NOISE_SEED, NOISE_SEED_LIMIT = seeds.NOISE_SEED, seeds.NOISE_SEED_LIMIT
CAMERA_NAMES = "lerobot/camera_name_mapping"
RENAME_MAP = "lerobot/rename_map"
N_ACTION_STEPS = "lerobot/n_action_steps"
ACTIONS = "actions"
#: Bounds on what a peer may send (a LIBERO render is at most this many pixels a side; names are short).
MAX_IMAGE_SIDE = 1024
MAX_TEXT = 4096
MAX_NAME = 256
MAX_MAP_ENTRIES = 32
#: LeRobot's default camera names on LIBERO (``LiberoEnv.camera_name_mapping=None``).
DEFAULT_CAMERA_NAMES = {"agentview_image": "image", "robot0_eye_in_hand_image": "image2"}


class InvalidRequest(ValueError):
    """A request that is not a LIBERO observation of this protocol; the message is sent to its client."""


class ReplyError(ValueError):
    """A reply that holds no usable action."""


def image_key(camera: str) -> str:
    return f"pixels/{camera}"


def request(
    images: tuple[np.ndarray, np.ndarray],
    robot_state: dict[str, np.ndarray],
    prompt: str,
    *,
    episode: str,
    step: int,
    seed: int,
    camera_names: dict[str, str],
    rename_map: dict[str, str],
    n_action_steps: int,
) -> dict[str, Any]:
    """One step's request: the raw images (agentview, wrist) and robot state exactly as given."""
    out: dict[str, Any] = {image_key(camera): image for camera, image in zip(CAMERAS, images)}
    out.update(robot_state)
    out.update(
        {
            PROMPT: prompt,
            EPISODE: episode,
            STEP: int(step),
            NOISE_SEED: int(seed),
            CAMERA_NAMES: dict(camera_names),
            RENAME_MAP: dict(rename_map),
            N_ACTION_STEPS: int(n_action_steps),
        }
    )
    return out


def _text(value: Any, key: str, limit: int) -> str:
    if not isinstance(value, str) or len(value) > limit:
        raise InvalidRequest(f"{key!r} must be a string of at most {limit} characters, got {describe(value)}")
    return value


def _count(value: Any, key: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= int(value) < 2**31:
        raise InvalidRequest(f"{key!r} must be a non-negative int, got {describe(value)}")
    return int(value)


def _names(value: Any, key: str) -> dict[str, str]:
    if not isinstance(value, dict) or len(value) > MAX_MAP_ENTRIES:
        raise InvalidRequest(f"{key!r} must be a map of at most {MAX_MAP_ENTRIES} names, got {describe(value)}")
    for name, target in value.items():
        _text(name, key, MAX_NAME)
        _text(target, key, MAX_NAME)
    return dict(value)


def validate_request(message: Any) -> dict[str, Any]:
    """``message`` if it is a valid step of this protocol, else :class:`InvalidRequest` saying what is wrong."""
    if not isinstance(message, dict):
        raise InvalidRequest(f"a request must be a map, got {type(message).__name__}")
    required = (*map(image_key, CAMERAS), *ROBOT_STATE, PROMPT, EPISODE, STEP, NOISE_SEED)
    missing = [key for key in required if key not in message]
    if missing:
        raise InvalidRequest(f"missing {', '.join(map(repr, missing))}")
    shapes = set()
    for camera in CAMERAS:
        image = message[image_key(camera)]
        if (
            not isinstance(image, np.ndarray)
            or image.dtype != np.uint8
            or image.ndim != 3
            or image.shape[2] != 3
            or not 0 < image.shape[0] <= MAX_IMAGE_SIDE
            or not 0 < image.shape[1] <= MAX_IMAGE_SIDE
        ):
            raise InvalidRequest(
                f"{image_key(camera)!r} must be a uint8 H x W x 3 image (sides up to {MAX_IMAGE_SIDE}), "
                f"got {describe(image)}"
            )
        shapes.add(image.shape)
    if len(shapes) != 1:
        raise InvalidRequest(f"both camera images must have one shape, got {sorted(shapes)}")
    for key, (_, shape) in ROBOT_STATE.items():
        value = message[key]
        if (
            not isinstance(value, np.ndarray)
            or value.dtype != np.float64
            or value.shape != shape
            or not np.all(np.isfinite(value))
        ):
            raise InvalidRequest(f"{key!r} must be a finite float64 array of shape {shape}, got {describe(value)}")
    _text(message[PROMPT], PROMPT, MAX_TEXT)
    _text(message[EPISODE], EPISODE, MAX_NAME)
    _count(message[STEP], STEP)
    if not is_noise_seed(message[NOISE_SEED]):
        raise InvalidRequest(f"{NOISE_SEED!r} must be an int in [0, 2**63), got {describe(message[NOISE_SEED])}")
    if set(_names(message.get(CAMERA_NAMES, DEFAULT_CAMERA_NAMES), CAMERA_NAMES)) != set(CAMERAS):
        raise InvalidRequest(f"{CAMERA_NAMES!r} must name both of LIBERO's cameras, {', '.join(CAMERAS)}")
    _names(message.get(RENAME_MAP, {}), RENAME_MAP)
    _count(message.get(N_ACTION_STEPS, 0), N_ACTION_STEPS)
    return message


def reply_action(reply: Any, action_dim: int = 7) -> np.ndarray:
    """The one action of a reply, (1, action_dim), in the dtype it was sent; :class:`ReplyError` otherwise."""
    if not isinstance(reply, dict) or ACTIONS not in reply:
        raise ReplyError(f"a reply must be a map with {ACTIONS!r}, got {describe(reply)}")
    actions = reply[ACTIONS]
    if not isinstance(actions, np.ndarray) or actions.dtype.kind != "f" or actions.shape != (1, action_dim):
        raise ReplyError(f"{ACTIONS!r} must be a float array of shape (1, {action_dim}), got {describe(actions)}")
    return actions
