"""Motion primitives as generators: each ``yield`` hands one action out and resumes at the next state.

A skill is written as straight-line code (``yield from move(...)``); the policy drives it one
observation at a time through :class:`Context`, whose ``scene`` is refreshed before every resume.
"""

from __future__ import annotations

from collections.abc import Callable, Generator
from dataclasses import dataclass, field

import numpy as np

from .control import OPEN, closest_frame, nearest_theta, orientation_error, servo
from .grasp import TIP_BELOW, clear_height
from .scene import Scene

Action = np.ndarray
Skill = Generator[Action, None, bool]
Target = np.ndarray | Callable[[Scene], np.ndarray]

MAX_Z = 1.42
"""Highest grip-site height used for transit (the arm still reaches every table position)."""


@dataclass
class Context:
    scene: Scene
    theta: float
    """Commanded finger angle; kept here so small tracking errors never accumulate."""
    frame: np.ndarray | None = None
    """A full commanded end-effector frame, when the gripper must not point straight down."""
    grip: float = OPEN
    table: float = 0.0
    """Height of the table top (lowest bottom of any movable object at the start)."""
    held: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def orientation(self):
        return self.theta if self.frame is None else self.frame

    def aim(self, frame: np.ndarray | None) -> None:
        """Command a full frame (None: back to pointing down), choosing the finger direction that
        needs the least rotation from where the gripper is now."""
        if frame is None:
            self.frame = None
            self.theta = nearest_theta(self.theta, self.scene.finger_theta)
            return
        self.frame = closest_frame(frame, self.scene.rot)


def move(
    ctx: Context,
    target: Target,
    *,
    tol: float = 0.006,
    max_steps: int = 150,
    speed: float = 1.0,
    theta_tol: float = 0.06,
    gain: float = 20.0,
    rot_limit: float = 1.0,
) -> Skill:
    """Servo the grip site to ``target`` (a point, or a function of the scene); True once there."""
    for _ in range(max_steps):
        s = ctx.scene
        goal = target(s) if callable(target) else target
        if np.linalg.norm(goal - s.eef) < tol and orientation_error(s, ctx.orientation) < theta_tol:
            return True
        yield servo(s, goal, ctx.orientation, ctx.grip, speed=speed, gain=gain, rot_limit=rot_limit)
    return False


def hold(ctx: Context, steps: int) -> Skill:
    pos = ctx.scene.eef.copy()
    for _ in range(steps):
        yield servo(ctx.scene, pos, ctx.orientation, ctx.grip)
    return True


def set_gripper(ctx: Context, grip: float, *, max_steps: int = 25, min_steps: int = 6) -> Skill:
    """Open or close in place until the fingers stop moving."""
    ctx.grip = grip
    pos = ctx.scene.eef.copy()
    last = ctx.scene.width
    for i in range(max_steps):
        yield servo(ctx.scene, pos, ctx.orientation, grip)
        width = ctx.scene.width
        if i + 1 >= min_steps and abs(width - last) < 4e-4:
            break
        last = width
    return True


def hang_below(ctx: Context) -> float:
    """How far the lowest point of the gripper or its load hangs under the grip site."""
    s = ctx.scene
    if ctx.held is not None and s.has(ctx.held):
        return max(TIP_BELOW, s.eef[2] - s.box(ctx.held)[0, 2])
    return TIP_BELOW


def transit(
    ctx: Context,
    target: Target,
    *,
    margin: float = 0.04,
    max_steps: int = 250,
    half_width: float = 0.07,
    approach: float = 0.0,
    tol: float = 0.008,
) -> Skill:
    """Up to a height that clears everything on the way, across, then down to ``target``.

    ``approach``: the last part of the descent is done straight down from this far above.
    """
    s = ctx.scene
    goal = target(s) if callable(target) else np.asarray(target, dtype=float)
    exclude = (ctx.held,) if ctx.held else ()
    width = half_width
    if ctx.held and s.has(ctx.held):
        ext = s.box(ctx.held)[1, :2] - s.box(ctx.held)[0, :2]
        width = max(half_width, float(np.max(ext)) / 2 + 0.03)
    top = clear_height(s, s.eef, goal, width, exclude=exclude)
    safe = max(top + hang_below(ctx) + margin, goal[2] + approach, s.eef[2])
    safe = min(safe, MAX_Z)
    steps = 0
    if s.eef[2] < safe - 0.015:
        lift = np.array([s.eef[0], s.eef[1], safe])
        yield from move(ctx, lift, tol=0.015, max_steps=60, theta_tol=10.0)

    # across, keeping the height; the target may move (re-read every step)
    def above(sc: Scene) -> np.ndarray:
        g = target(sc) if callable(target) else goal
        return np.array([g[0], g[1], max(safe, g[2])])

    ok = yield from move(ctx, above, tol=0.012, max_steps=max_steps, theta_tol=0.1)
    steps += 1
    ok = yield from move(ctx, target, tol=tol, max_steps=100, speed=0.6)
    return ok
