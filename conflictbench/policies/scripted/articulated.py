"""Articulated fixtures: drawers (slide joints), the microwave door and the stove knob (hinges).

Which way is "open": LIBERO's fixtures open toward the end of the joint range farther from zero
(drawers to -0.16 m, the microwave door to -2.09 rad) and are closed at the end nearer zero.
"""

from __future__ import annotations

import math

import numpy as np

from conflictbench.core import JointInfo

from .control import CLOSE, OPEN, side_frame
from .primitives import Context, Skill, hold, move, set_gripper, transit
from .scene import Scene

UP = np.array([0.0, 0.0, 1.0])
CLOSE_TILT = 0.5
"""Radians from straight down that the gripper leans toward a drawer it pushes shut."""


def _far_end(j: JointInfo) -> float:
    lo, hi = j.range
    return float(lo if abs(lo) > abs(hi) else hi)


def _near_end(j: JointInfo) -> float:
    lo, hi = j.range
    return float(hi if abs(lo) > abs(hi) else lo)


def _opened(j: JointInfo) -> float:
    """How far open a joint is, as a fraction of its range."""
    far, near = _far_end(j), _near_end(j)
    return (j.qpos - near) / (far - near)


def _handle(s: Scene, body: str, pull: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, half-extent along ``pull``, front point) of the part of ``body`` sticking out most along ``pull``."""
    boxes = s.frames(body)
    centers, ext = boxes.centers, boxes.reach(pull)
    front = centers @ pull + ext
    k = int(np.argmax(front))
    return centers[k], ext[k], centers[k] + pull * ext[k]


def opening_sweep(s: Scene, region: str) -> np.ndarray | None:
    """World box (2, 3) a region's drawer will occupy once open (None: not a closed drawer)."""
    for name in s.joints_of(region):
        j = s.joint(name)
        if j.kind != "slide" or _opened(j) >= 0.8:
            continue
        axis = np.asarray(j.axis, dtype=float)
        shift = axis * (_far_end(j) * 0.95 - j.qpos)
        box = s.box(j.body)
        moved = box + shift
        return np.stack([np.minimum(box[0], moved[0]), np.maximum(box[1], moved[1])])
    return None


def ensure_open(ctx: Context, region: str) -> Skill:
    """Open the drawer or door that a region belongs to, if it is not open enough to put things in."""
    for name in ctx.scene.joints_of(region):
        if _opened(ctx.scene.joint(name)) < 0.8:
            ok = yield from _slide(ctx, name, opened=True) if ctx.scene.joint(name).kind == "slide" else _noop()
            if not ok:
                return False
    return True


def _noop() -> Skill:
    return False
    yield


def set_open(ctx: Context, name: str, opened: bool) -> Skill:
    joints = ctx.scene.joints_of(name)
    if not joints:
        ctx.notes.append(f"{name} has no joint")
        return False
    ok = True
    for jn in joints:
        if ctx.scene.joint(jn).kind == "slide":
            ok = (yield from _slide(ctx, jn, opened)) and ok
        else:
            ok = (yield from _door(ctx, jn, opened)) and ok
    return ok


def _retreat(ctx: Context, direction: np.ndarray, distance: float = 0.08) -> Skill:
    """Let go, back off along ``direction``, then turn the gripper to point down again."""
    yield from set_gripper(ctx, OPEN, max_steps=12)
    yield from move(ctx, ctx.scene.eef + direction * distance, tol=0.015, max_steps=30)
    up = ctx.scene.eef + np.array([0.0, 0.0, 0.06])
    ctx.aim(None)
    yield from move(ctx, up, tol=0.02, max_steps=40, theta_tol=0.15, rot_limit=0.4)


def _slide(ctx: Context, joint: str, opened: bool) -> Skill:
    """Open a drawer by pulling its handle, or close it by pushing its front.

    The gripper works horizontally, pointing at the cabinet: from above it would collide with the
    handle and front of the drawer above.
    """
    s = ctx.scene
    j = s.joint(joint)
    axis = np.asarray(j.axis, dtype=float)
    pull = axis * math.copysign(1.0, _far_end(j))  # world direction the drawer moves when opening
    pull[2] = 0.0
    pull /= np.linalg.norm(pull)
    side = np.cross(UP, pull)
    center, half, front = _handle(s, j.body, pull)
    target_q = _far_end(j) * 0.95 if opened else _near_end(j)
    travel = abs(target_q - j.qpos)  # metres the front still has to move

    if opened:
        frame = side_frame(-pull, UP)  # fingers close vertically on the handle bar
        grip_at = lambda sc: _handle(sc, j.body, pull)[0]  # noqa: E731
    else:
        # closed fingers side by side, tips leading: the hand trails up and back, clear of the
        # table and of the drawer above (held horizontal, the arm cannot reach a bottom drawer)
        lean = np.array([0.0, 0.0, -math.cos(CLOSE_TILT)]) - pull * math.sin(CLOSE_TILT)
        frame = side_frame(lean, side)
        grip_at = lambda sc: _handle(sc, j.body, pull)[2] + pull * 0.012  # noqa: E731
    ctx.grip = OPEN if opened else CLOSE
    stage = grip_at(s) + pull * 0.14
    ctx.aim(None)
    yield from transit(ctx, stage + np.array([0.0, 0.0, 0.06]), tol=0.02)
    ctx.aim(frame)
    yield from move(ctx, stage, tol=0.01, max_steps=60, theta_tol=0.08, rot_limit=0.4)
    yield from move(ctx, lambda sc: grip_at(sc) + pull * 0.05, tol=0.008, max_steps=40)
    yield from move(ctx, grip_at, tol=0.005, max_steps=40, speed=0.4)
    if opened:
        yield from set_gripper(ctx, CLOSE, max_steps=15)
        if ctx.scene.width < 0.004:
            ctx.notes.append(f"missed the handle of {joint}")
            yield from _retreat(ctx, pull)
            return False
    start = ctx.scene.eef.copy()
    end = start + pull * (travel + 0.01) * (1 if opened else -1)
    for _ in range(3):
        yield from move(ctx, end, tol=0.006, max_steps=60, speed=0.5)
        q = ctx.scene.joint(joint).qpos
        if (opened and _opened(ctx.scene.joint(joint)) > 0.93) or (not opened and abs(q - _near_end(j)) < 0.004):
            break
        end = end + pull * 0.01 * (1 if opened else -1)
    yield from _retreat(ctx, pull)
    return True


def _door(ctx: Context, joint: str, opened: bool) -> Skill:
    """Swing a hinged door (the microwave's) by pushing its upper edge along its arc."""
    s = ctx.scene
    j = s.joint(joint)
    anchor = np.asarray(j.anchor, dtype=float)
    axis = np.asarray(j.axis, dtype=float)
    target_q = _far_end(j) * 0.9 if opened else _near_end(j)
    sign = math.copysign(1.0, target_q - j.qpos)

    def panel(sc: Scene) -> tuple[np.ndarray, np.ndarray, float, float]:
        part = sc.frames(j.body)
        centers, rots, halves = part.centers, part.rots, part.halves
        k = int(np.argmax(np.prod(halves, axis=1)))
        c = centers[k]
        u = c - anchor
        u[2] = 0.0
        length = 2 * np.linalg.norm(u)
        u /= np.linalg.norm(u)
        thick = float(np.abs(rots[k].T @ np.cross(axis, u)) @ halves[k])
        top = float(c[2] + np.abs(rots[k][2]) @ halves[k])
        return u, np.cross(axis, u) * sign, length, thick, top

    def contact(sc: Scene, lead: float) -> np.ndarray:
        u, v, length, thick, top = panel(sc)
        r = 0.75 * length
        c, sn = math.cos(lead * sign), math.sin(lead * sign)
        ur = np.array([c * u[0] - sn * u[1], sn * u[0] + c * u[1], 0.0])
        vr = np.cross(axis, ur) * sign
        return np.array([anchor[0], anchor[1], top - 0.022]) + ur * r - vr * (thick + 0.014)

    u, _, _, _, _ = panel(s)
    ctx.aim(None)
    ctx.theta = _nearest(math.atan2(u[1], u[0]), s.finger_theta)
    ctx.grip = CLOSE
    yield from transit(ctx, lambda sc: contact(sc, -0.05), tol=0.008)
    for _ in range(200):
        q = ctx.scene.joint(joint).qpos
        if (sign > 0 and q >= target_q - 0.002) or (sign < 0 and q <= target_q + 0.002):
            break
        u, _, _, _, _ = panel(ctx.scene)
        ctx.theta = _nearest(math.atan2(u[1], u[0]), ctx.theta)
        yield from move(ctx, contact(ctx.scene, 0.25), tol=0.004, max_steps=1, speed=0.5)
    yield from hold(ctx, 3)
    yield from move(ctx, ctx.scene.eef + np.array([0.0, 0.0, 0.08]), tol=0.02, max_steps=30)
    return True


def _nearest(theta: float, current: float) -> float:
    from .control import nearest_theta

    return nearest_theta(theta, current)


def turn(ctx: Context, name: str, on: bool) -> Skill:
    """Turn a knob (the stove's): grasp its lever over the hinge axis and twist the wrist."""
    joints = [jn for jn in ctx.scene.joints_of(name) if ctx.scene.joint(jn).kind == "hinge"]
    if not joints:
        ctx.notes.append(f"{name} has no knob")
        return False
    joint = joints[0]
    s = ctx.scene
    j = s.joint(joint)
    anchor = np.asarray(j.anchor, dtype=float)
    axis_sign = math.copysign(1.0, j.axis[2])
    target_q = 0.9 if on else _near_end(j)

    def lever(sc: Scene) -> tuple[np.ndarray, float]:
        boxes = sc.frames(sc.joint(joint).body)
        centers, rots, halves, tops = boxes.centers, boxes.rots, boxes.halves, boxes.tops
        k = int(np.argmax(tops))
        horiz = [i for i in range(3) if abs(rots[k][2, i]) < 0.5]
        long_i = max(horiz, key=lambda i: halves[k][i])
        long_axis = rots[k][:, long_i]
        along = float(np.clip((anchor - centers[k]) @ long_axis, -halves[k][long_i] + 0.01, halves[k][long_i] - 0.01))
        point = centers[k] + long_axis * along
        point[2] = tops[k] - 0.018
        across = math.atan2(long_axis[1], long_axis[0]) + math.pi / 2
        return point, across

    point, across = lever(s)
    ctx.aim(None)
    ctx.theta = _nearest(across, s.finger_theta)
    yield from set_gripper(ctx, OPEN, max_steps=8, min_steps=1) if ctx.grip != OPEN else _noop()
    yield from transit(ctx, lambda sc: lever(sc)[0] + np.array([0.0, 0.0, 0.05]), tol=0.01)
    yield from move(ctx, lambda sc: lever(sc)[0], tol=0.005, max_steps=40, speed=0.4)
    yield from set_gripper(ctx, CLOSE, max_steps=12)
    start_theta, start_q = ctx.theta, ctx.scene.joint(joint).qpos
    for _ in range(60):
        q = ctx.scene.joint(joint).qpos
        if (on and q >= target_q - 0.05) or (not on and q <= target_q + 0.02):
            break
        ctx.theta = start_theta + axis_sign * (target_q - start_q) * 1.15
        yield from move(
            ctx, anchor * np.array([1, 1, 0]) + np.array([0, 0, point[2]]), tol=0.0, max_steps=1, rot_limit=0.3
        )
    yield from set_gripper(ctx, OPEN, max_steps=10)
    yield from move(ctx, ctx.scene.eef + np.array([0.0, 0.0, 0.08]), tol=0.02, max_steps=30)
    return True
