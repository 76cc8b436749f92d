"""Low-level control: turning a desired gripper pose into LIBERO's 7-D delta action.

LIBERO's OSC_POSE controller reads ``a[:3]`` as a position offset of ``0.05 * a`` metres and
``a[3:6]`` as a world-frame rotation of ``0.5 * a`` radians (axis-angle), both relative to the
current pose, clipped to [-1, 1]; ``a[6]`` is the gripper (-1 open, +1 close).
"""

from __future__ import annotations

import math

import numpy as np

from .scene import Scene, finger_frame, rotvec, wrap

OPEN, CLOSE = -1.0, 1.0
POS_GAIN = 20.0
"""Proportional gain on the position error: within 5 cm the controller's goal is the target itself;
further away the action saturates (the arm then moves about 12 mm a step)."""
ROT_GAIN = 1.0
"""Fraction of the orientation error corrected per step (0.5 rad of rotation per unit action)."""


def servo(
    scene: Scene,
    target: np.ndarray,
    orientation,
    grip: float,
    *,
    speed: float = 1.0,
    gain: float = POS_GAIN,
    rot_limit: float = 1.0,
) -> np.ndarray:
    """One action toward ``target`` (grip-site position) and ``orientation``: a finger angle for
    the gripper pointing down, or a full 3x3 end-effector frame."""
    action = np.zeros(7)
    action[:3] = np.clip(gain * (np.asarray(target, dtype=float) - scene.eef), -speed, speed)
    rot = finger_frame(orientation) if np.ndim(orientation) == 0 else np.asarray(orientation)
    err = rotvec(rot @ scene.rot.T)
    action[3:6] = np.clip(ROT_GAIN * err / 0.5, -rot_limit, rot_limit)
    action[6] = grip
    return action


def nearest_theta(theta: float, current: float) -> float:
    """The fingers are symmetric: of ``theta`` and ``theta + pi``, the one closer to ``current``."""
    a = current + wrap(theta - current)
    b = current + wrap(theta + math.pi - current)
    return a if abs(a - current) <= abs(b - current) else b


def orientation_error(scene: Scene, orientation) -> float:
    """Angle (rad) between the end effector's frame and ``orientation`` (finger angle or frame)."""
    rot = finger_frame(orientation) if np.ndim(orientation) == 0 else np.asarray(orientation)
    return float(np.linalg.norm(rotvec(rot @ scene.rot.T)))


def side_frame(approach: np.ndarray, fingers: np.ndarray) -> np.ndarray:
    """End-effector frame pointing along ``approach`` with the fingers closing along ``fingers``."""
    z = np.asarray(approach, dtype=float) / np.linalg.norm(approach)
    y = np.asarray(fingers, dtype=float)
    y = y - z * (y @ z)
    y = y / np.linalg.norm(y)
    return np.stack([np.cross(y, z), y, z], axis=1)


def closest_frame(frame: np.ndarray, current: np.ndarray) -> np.ndarray:
    """``frame`` or the same frame rolled half a turn about its approach axis (the fingers are
    symmetric), whichever is the smaller rotation away from ``current``."""
    flipped = frame * np.array([-1.0, -1.0, 1.0])
    a = np.linalg.norm(rotvec(frame @ current.T))
    b = np.linalg.norm(rotvec(flipped @ current.T))
    return frame if a <= b else flipped
