"""Putting an object into a roofed container (the microwave) through its open side.

From above, the hand would meet the roof: a mug is 10 cm tall and the microwave 14 cm inside. So
the object is carried by its handle with the hand beside it, slid in at floor height until the
hand reaches the roof's front edge, let go, and pushed the rest of the way by closed fingers
whose hand trails up and back, below and in front of the roof.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .control import CLOSE, OPEN, side_frame
from .grasp import HAND_BOTTOM, plan_grasp, support_height
from .primitives import Context, Skill, hold, move, set_gripper, transit
from .scene import Boxes, Scene, wrap

HAND_HALF_DEPTH = 0.032
"""Half the hand's thickness across its fingers' closing axis."""
PUSH_TILT = 0.6
"""Radians the pusher leans, fingertips first, so its hand stays below and in front of the roof."""
DOOR_CLEARANCE = 0.012
"""The object ends this far behind the roof's front edge, out of the closing door's way."""


@dataclass(frozen=True)
class Opening:
    inward: np.ndarray
    """Unit xy direction from the open side into the container."""
    lateral: np.ndarray
    floor: float
    roof: float
    edge: float
    """The roof's front edge, as a coordinate along ``inward``."""
    back: float
    """The back wall's inner face along ``inward``."""
    middle: float
    """Midway between the side walls, as a coordinate along ``lateral``."""


UP = np.array([0.0, 0.0, 1.0])
SIDES = ((1, 0), (-1, 0), (0, 1), (0, -1))


def _ray(boxes: Boxes, start: np.ndarray, direction, reach: float = 0.4) -> float | None:
    """Distance along ``direction`` (xy) from ``start`` to the first of ``boxes`` (4 mm steps), or None."""
    ts = np.arange(0.0, reach, 0.004)
    inside = boxes.contains(start + np.outer(ts, [direction[0], direction[1], 0.0])).any(axis=1)
    return float(ts[np.argmax(inside)]) if inside.any() else None


def _side(v: np.ndarray) -> tuple[int, int]:
    return int(round(v[0])), int(round(v[1]))


def opening(s: Scene, region: str, height: float) -> Opening | None:
    """The open side of a region whose container has a roof too low for a hand above an object
    ``height`` tall (None: no such roof, or no single open side)."""
    site = s.site(region)
    parent = site.parent
    if site.joints or not parent:
        return None  # drawers open out from under what is above them
    boxes = s.frames(parent)
    centre = np.asarray(site.pos, dtype=float)
    floor = support_height(s, centre[:2], below=centre[2], exclude=tuple(n for n in s.objects() if n != parent))
    if floor is None:
        return None
    bottoms = boxes.centers[:, 2] - boxes.reach(UP)
    over = bottoms > centre[2]
    above = boxes.contains(np.array([[centre[0], centre[1], z] for z in np.arange(centre[2], centre[2] + 0.3, 0.004)]))
    hit = above.any(axis=0) & over
    if not hit.any():
        return None
    roof = float(bottoms[hit].min())
    if roof - floor > height + HAND_BOTTOM + 0.06:
        return None
    mid = np.array([centre[0], centre[1], (floor + roof) / 2])
    dist = {side: _ray(boxes, mid, side) for side in SIDES}
    open_sides = [side for side, t in dist.items() if t is None]
    if len(open_sides) != 1:
        return None
    inward = -np.array(open_sides[0], dtype=float)
    lateral = np.array([-inward[1], inward[0]])
    back = float(mid[:2] @ inward) + dist[_side(inward)]
    middle = float(mid[:2] @ lateral) + (dist[_side(lateral)] - dist[_side(-lateral)]) / 2
    # the roof's front edge: the outermost point of the geoms over the region
    inward3 = np.append(inward, 0.0)
    edge = float((boxes.centers[hit] @ inward3 - boxes.reach(inward3)[hit]).min())
    return Opening(inward, lateral, floor, roof, edge, back, middle)


def _extent(s: Scene, name: str, axis: np.ndarray) -> tuple[float, float]:
    """The object's reach (behind, ahead) along ``axis`` (xy) relative to its origin."""
    boxes = s.frames(name)
    a3 = np.array([axis[0], axis[1], 0.0])
    proj, ext = boxes.centers @ a3, boxes.reach(a3)
    origin = s.pos(name) @ a3
    return float((proj - ext).min() - origin), float((proj + ext).max() - origin)


def way_in(s: Scene, name: str, region: str) -> Opening | None:
    """The opening to put ``name`` into ``region`` through, when it needs one and has a handle to be
    carried by (None: put it in from above as usual)."""
    o = opening(s, region, float(s.box(name)[1, 2] - s.box(name)[0, 2]))
    return o if o is not None and plan_grasp(s, name, kind="handle") is not None else None


def insert(ctx: Context, name: str, o: Opening) -> Skill:
    """Carry ``name`` by its handle through the opening ``o``, push it home, and turn the wrist
    back to where it started."""
    return (yield from _unwound(ctx, _insert(ctx, name, o)))


def _unwound(ctx: Context, skill: Skill) -> Skill:
    """Run ``skill``, then turn the wrist back the way it came.

    Planners choose finger angles modulo pi, and the shortest turn from there to the next skill's
    angle can be the long way round for the arm's last joint, which then stops at its limit.
    """
    turned, last = 0.0, ctx.scene.finger_theta
    try:
        action = next(skill)
        while True:
            yield action
            now = ctx.scene.finger_theta
            turned, last = turned + wrap(now - last), now
            action = skill.send(None)
    except StopIteration as stop:
        result = stop.value
    ctx.aim(None)
    here = ctx.scene.eef.copy()
    for _ in range(6):
        if abs(turned) < 0.1:
            break
        ctx.theta = ctx.scene.finger_theta - float(np.clip(turned, -math.pi / 4, math.pi / 4))
        before = ctx.scene.finger_theta
        yield from move(ctx, here, tol=0.02, max_steps=25, theta_tol=0.08, rot_limit=0.5)
        turned += wrap(ctx.scene.finger_theta - before)
    return result


def _insert(ctx: Context, name: str, o: Opening) -> Skill:
    from .pick_place import pick

    s = ctx.scene
    behind, ahead = _extent(s, name, o.inward)
    # where the origin ends: clear of the door, short of the back wall
    final = min(o.edge + DOOR_CLEARANCE - behind, o.back - 0.008 - ahead)
    lat = o.middle - float((s.box(name).mean(axis=0)[:2] - s.pos(name)[:2]) @ o.lateral)

    def origin_at(depth: float) -> np.ndarray:
        return o.inward * depth + o.lateral * lat

    if not (yield from pick(ctx, name, then_xy=origin_at(final), kind="handle")):
        return False
    s = ctx.scene
    grip = s.eef - s.pos(name)  # the hand relative to the object's origin, as held
    under = s.eef[2] - s.box(name)[0, 2]
    z = o.floor + 0.008 + under
    # set down as deep as the hand allows; start from where the whole object is still outside
    down = min(final, o.edge - HAND_HALF_DEPTH - 0.01 - float(grip[:2] @ o.inward))
    stage = o.edge - 0.015 - ahead
    eef_at = lambda depth: np.append(origin_at(depth) + grip[:2], z)  # noqa: E731
    yield from transit(ctx, eef_at(stage), tol=0.01)
    yield from move(ctx, eef_at(down), tol=0.006, max_steps=60, speed=0.4)
    yield from move(ctx, eef_at(down) - np.array([0.0, 0.0, 0.006]), tol=0.004, max_steps=20, speed=0.3)
    yield from hold(ctx, 3)
    yield from set_gripper(ctx, OPEN, max_steps=15)
    ctx.held = None
    back_off = ctx.scene.eef - np.append(o.inward, 0.0) * 0.06
    yield from move(ctx, back_off, tol=0.01, max_steps=30)
    return (yield from _push_in(ctx, name, o, final))


def _push_in(ctx: Context, name: str, o: Opening, final: float) -> Skill:
    """Slide ``name`` along ``o.inward`` until its origin is at depth ``final``."""
    inward3 = np.append(o.inward, 0.0)
    lean = -UP * math.cos(PUSH_TILT) + inward3 * math.sin(PUSH_TILT)
    ctx.aim(side_frame(lean, np.append(o.lateral, 0.0)))
    ctx.grip = CLOSE
    behind, _ = _extent(ctx.scene, name, o.inward)
    push_z = o.floor + 0.045

    def contact(sc: Scene, ahead: float) -> np.ndarray:
        front = sc.pos(name)[:2] + o.inward * (behind + ahead - 0.012)
        return np.array([front[0], front[1], push_z])

    start = contact(ctx.scene, -0.05)
    yield from move(ctx, start + np.array([0.0, 0.0, 0.04]), tol=0.015, max_steps=60, rot_limit=0.4)
    yield from move(ctx, start, tol=0.008, max_steps=40, theta_tol=0.1)
    for _ in range(150):
        if float(ctx.scene.pos(name)[:2] @ o.inward) >= final - 0.003:
            break
        yield from move(ctx, lambda sc: contact(sc, 0.02), tol=0.0, max_steps=1, speed=0.4)
    done = float(ctx.scene.pos(name)[:2] @ o.inward) >= final - 0.01
    yield from move(ctx, ctx.scene.eef - inward3 * 0.08, tol=0.015, max_steps=30)
    ctx.aim(None)
    yield from move(
        ctx, ctx.scene.eef + np.array([0.0, 0.0, 0.06]), tol=0.02, max_steps=40, theta_tol=0.15, rot_limit=0.4
    )
    yield from set_gripper(ctx, OPEN, max_steps=8, min_steps=1)
    return done
