"""Picking an object up and putting it on or in something."""

from __future__ import annotations

import numpy as np

from .control import CLOSE, OPEN, nearest_theta, side_frame
from .grasp import TIP_BELOW, collisions, gripper_points, plan_grasp, reach_cost, support_height
from .primitives import Context, Skill, hold, move, set_gripper, transit
from .scene import Scene

MIN_HOLD_WIDTH = 0.004
"""Closed fingers further apart than this are holding something."""


def grasped(s: Scene, name: str) -> bool:
    return s.width > MIN_HOLD_WIDTH and s.touching(name)


def pick(ctx: Context, name: str, then_xy=None, kind: str | None = None) -> Skill:
    """Grasp ``name`` and lift it clear of its support; True if it came up with the gripper.

    ``then_xy``: where it will be carried (a point or a function of the scene), to prefer grasps
    that leave the arm a comfortable reach there. ``kind``: only grasps of that kind (``handle``).
    """
    if ctx.grip == CLOSE:
        yield from set_gripper(ctx, OPEN)

    def plan(s: Scene):
        dest = then_xy(s) if callable(then_xy) else then_xy
        return plan_grasp(s, name, then_xy=dest, kind=kind)

    grasp = plan(ctx.scene)
    ctx.theta = grasp.theta
    start = ctx.scene.pos(name).copy()

    def pre(s: Scene) -> np.ndarray:
        return plan(s).point + np.array([0.0, 0.0, 0.06])

    yield from transit(ctx, pre, approach=0.0)
    grasp = plan(ctx.scene)  # the object may have been nudged: plan again from close by
    ctx.theta = grasp.theta
    yield from move(ctx, grasp.point + np.array([0.0, 0.0, 0.06]), tol=0.01, max_steps=40)
    yield from move(ctx, grasp.point, tol=0.005, max_steps=60, speed=0.5)
    yield from set_gripper(ctx, CLOSE, max_steps=20, min_steps=8)
    if not grasped(ctx.scene, name):
        ctx.notes.append(f"missed {name}")
        yield from set_gripper(ctx, OPEN)
        yield from move(ctx, ctx.scene.eef + np.array([0.0, 0.0, 0.08]), tol=0.02, max_steps=30)
        return False
    ctx.held = name
    lift = ctx.scene.eef + np.array([0.0, 0.0, 0.08])
    yield from move(ctx, lift, tol=0.02, max_steps=40, speed=0.7)
    # risen with the fingers still on it: held (a thin bowl wall squeezes to about the width of
    # fingers closed on nothing, so the width alone cannot tell)
    if ctx.scene.pos(name)[2] < start[2] + 0.03 or not ctx.scene.touching(name):
        ctx.notes.append(f"dropped {name}")
        ctx.held = None
        yield from set_gripper(ctx, OPEN)
        return False
    return True


def place(ctx: Context, name: str, goal_xy, drop: float = 0.012) -> Skill:
    """Carry the held ``name`` so that its body origin is over ``goal_xy`` (a point or a function
    of the scene), lower it until its bottom is ``drop`` above whatever is under it, and let go."""

    def goal_of(s: Scene) -> np.ndarray:
        return np.asarray(goal_xy(s) if callable(goal_xy) else goal_xy, dtype=float)[:2]

    def eef_for(s: Scene, height: float) -> np.ndarray:
        # keep the object-in-hand offset measured now: the object may have shifted in the grasp
        offset = s.eef - s.pos(name)
        xy = goal_of(s) + offset[:2]
        return np.array([xy[0], xy[1], height])

    s = ctx.scene
    bottom_off = s.eef[2] - s.box(name)[0, 2]  # grip site above the object's lowest point
    ext = (s.box(name)[1, :2] - s.box(name)[0, :2]) / 2

    def support(sc: Scene) -> float:
        xy = goal_of(sc) + (sc.box(name)[0, :2] + sc.box(name)[1, :2]) / 2 - sc.pos(name)[:2]
        h = support_height(sc, xy, below=sc.box(name)[0, 2] + 0.005, exclude=(name,), half=float(min(ext)) * 0.5)
        return ctx.table if h is None else max(h, ctx.table)

    def release_eef(sc: Scene) -> np.ndarray:
        return eef_for(sc, support(sc) + drop + bottom_off)

    yield from transit(ctx, lambda sc: eef_for(sc, support(sc) + drop + bottom_off + 0.05), tol=0.01)
    yield from move(ctx, release_eef, tol=0.004, max_steps=60, speed=0.4)
    yield from hold(ctx, 3)
    yield from set_gripper(ctx, OPEN, max_steps=15)
    ctx.held = None
    up = ctx.scene.eef + np.array([0.0, 0.0, 0.10])
    yield from move(ctx, up, tol=0.02, max_steps=30)
    return True


def is_flat(s: Scene, name: str) -> bool:
    """Too wide for the fingers and too low to get under: a plate is pushed, not carried."""
    lg = s.local_geoms(name)
    ext = lg[:, 1].max(axis=0) - lg[:, 0].min(axis=0)
    return ext[2] < 0.03 and min(ext[0], ext[1]) > 0.075


PUSH_BACKOFF = 0.02
"""The pusher comes down this far behind the object before moving in."""
PUSH_TILT = 0.45
"""Radians the pusher leans forward: the hand then rides over the pushed object, not behind it
(where a cabinet or another object may stand)."""


def pusher_frame(d: np.ndarray) -> np.ndarray:
    """Closed gripper leaning toward the push direction ``d`` (xy), fingers side by side across it."""
    d3 = np.array([d[0], d[1], 0.0]) / max(float(np.linalg.norm(d)), 1e-9)
    approach = np.array([0.0, 0.0, -np.cos(PUSH_TILT)]) - d3 * np.sin(PUSH_TILT)
    return side_frame(approach, np.cross([0.0, 0.0, 1.0], d3))


def _pusher_clear(s: Scene, name: str, start: np.ndarray, end: np.ndarray, radius: float, table: float) -> int:
    """Collisions of the closed gripper set behind ``name`` at ``start`` to push it toward ``end``."""
    d = end - start
    d = d / max(float(np.linalg.norm(d)), 1e-6)
    xy = start - d * (radius + 0.012 + PUSH_BACKOFF)
    point = np.array([xy[0], xy[1], table + TIP_BELOW + 0.004])
    frame = pusher_frame(d)  # it comes down along its own axis, already leaning
    pts = np.concatenate([gripper_points(point - frame[:, 2] * k, frame, closed=True) for k in (0.0, 0.05, 0.1)])
    return collisions(pts, s.solids(exclude=(name,)), margin=0.002)


def _sweep_hits(s: Scene, name: str, start: np.ndarray, end: np.ndarray, radius: float) -> int:
    """How many other geoms the object's footprint (a disc) would run into on its way start-end."""
    boxes = s.solids(exclude=(name,))
    if len(boxes) == 0:
        return 0
    bottom = s.box(name)[0, 2]
    tall = boxes.tops > bottom + 0.006
    hit = np.zeros(len(boxes), dtype=bool)
    for t in np.linspace(0.0, 1.0, 6):
        c = start + t * (end - start)
        rel = np.array([c[0], c[1], 0.0])[None] - boxes.centers
        rel[:, 2] = 0.0
        local = np.abs(np.einsum("bi,bij->bj", rel, boxes.rots))
        gap = np.maximum(local - boxes.halves, 0.0)
        gap[np.abs(boxes.rots[:, 2, :]) > 0.7] = 0.0  # ignore the vertical axis
        hit |= (np.linalg.norm(gap, axis=1) < radius) & tall
    return int(hit.sum())


def plan_push(s: Scene, name: str, goal: np.ndarray, radius: float, table: float) -> list[np.ndarray]:
    """Waypoints for the object's origin: straight to ``goal``, or via the intermediate point
    that best frees the gripper's place behind the object and the object's way (fewest
    collisions, then least detour)."""
    p = s.pos(name)[:2]
    direct = float(np.linalg.norm(goal - p))

    def cost_of(legs: list[np.ndarray]) -> float:
        hits, here, length, reach = 0, p, 0.0, 0.0
        for to in legs:
            hits += _pusher_clear(s, name, here, to, radius, table) + 3 * _sweep_hits(s, name, here, to, radius + 0.01)
            length += float(np.linalg.norm(to - here))
            d = (to - here) / max(float(np.linalg.norm(to - here)), 1e-6)
            reach += reach_cost(here - d * (radius + 0.03))
            here = to
        return 0.01 * hits + 0.2 * (length - direct) + 0.005 * (len(legs) - 1) + 0.2 * reach

    options = [[goal], [np.array([p[0], goal[1]]), goal], [np.array([goal[0], p[1]]), goal]]
    for k in range(24):
        phi = 2 * np.pi * k / 24
        for dist in (0.06, 0.1, 0.15, 0.2, 0.25):
            options.append([p + dist * np.array([np.cos(phi), np.sin(phi)]), goal])
    return min(options, key=cost_of)


def push(ctx: Context, name: str, goal_xy, tolerance: float = 0.01) -> Skill:
    """Slide ``name`` across the table until its origin is within ``tolerance`` of ``goal_xy``,
    pushing it with the closed fingertips from the side away from the goal (via one intermediate
    point when the gripper does not fit behind it on the straight line)."""

    def goal_of(s: Scene) -> np.ndarray:
        return np.asarray(goal_xy(s) if callable(goal_xy) else goal_xy, dtype=float)[:2]

    lg = ctx.scene.local_geoms(name)
    radius = float(np.max(lg[:, 1, :2].max(axis=0) - lg[:, 0, :2].min(axis=0)) / 2)

    def behind(s: Scene, to: np.ndarray, ahead: float) -> np.ndarray:
        p = s.pos(name)[:2]
        d = to - p
        dist = float(np.linalg.norm(d))
        d = d / max(dist, 1e-6)
        xy = p + d * (min(ahead, dist) - radius - 0.012)
        return np.array([xy[0], xy[1], ctx.table + TIP_BELOW + 0.004])

    if ctx.grip != CLOSE:
        yield from set_gripper(ctx, CLOSE, max_steps=10)
    for _ in range(5):  # approaches: re-planned whenever the object turns away from the pusher's line
        s = ctx.scene
        if np.linalg.norm(goal_of(s) - s.pos(name)[:2]) < tolerance:
            break
        legs = plan_push(s, name, goal_of(s), radius, ctx.table)
        to = legs[0]
        last = len(legs) == 1
        d = to - s.pos(name)[:2]
        ctx.theta = nearest_theta(float(np.arctan2(d[1], d[0])) + np.pi / 2, s.finger_theta)
        start = behind(s, to, -PUSH_BACKOFF)
        frame = pusher_frame(d)
        above = start - frame[:, 2] * 0.12  # back along the leaning approach axis
        yield from transit(ctx, above, tol=0.01)
        ctx.aim(frame)
        yield from move(ctx, above, tol=0.01, max_steps=40, rot_limit=0.4)
        yield from move(ctx, start, tol=0.006, max_steps=40)
        for _ in range(150):
            s = ctx.scene
            aim = goal_of(s) if last else to
            p = s.pos(name)[:2]
            if np.linalg.norm(aim - p) < (tolerance if last else 0.02):
                break
            heading = (aim - p) / np.linalg.norm(aim - p)
            contact = (p - s.eef[:2]) / max(float(np.linalg.norm(p - s.eef[:2])), 1e-6)
            if heading @ contact < np.cos(np.radians(30)):
                break  # it slid sideways: come round and push again from behind
            yield from move(ctx, behind(s, aim, 0.03), tol=0.0, max_steps=1, speed=0.5)
        yield from move(ctx, ctx.scene.eef + np.array([0.0, 0.0, 0.08]), tol=0.02, max_steps=30)
        ctx.aim(None)
    return True
