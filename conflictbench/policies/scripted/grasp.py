"""Grasp planning from collision geometry, and clearance checks for the gripper.

A grasp is a grip-site position and a finger angle. Candidates come from the object's collision
boxes in its own frame: the deepest band under the top that fits between the open fingers (the
cap of a bottle, a box, the knob of a moka pot's lid), or, when the top is too wide (bowls, mugs),
points on the rim with the fingers straddling the wall. Each candidate is scored by how much of a
sampled model of the open gripper, and of the column above it, would intersect other geometry.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .control import nearest_theta
from .scene import Boxes, Scene, finger_frame, wrap

MAX_SPAN = 0.068
"""Widest part the open fingers (about 0.078 apart) close on with some margin."""
PAD_BELOW, PAD_ABOVE = 0.005, 0.012
"""The finger pads span this far below/above the grip site."""
TIP_BELOW = 0.010
"""Fingertips reach this far below the grip site."""
ROBOT_BASE_XY = np.array([-0.66, 0.0])


def _grid(lo, hi, n) -> np.ndarray:
    axes = [np.linspace(a, b, k) for a, b, k in zip(lo, hi, n)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


# Points of the open gripper in its own frame: (along the finger axis, across it, up from the grip site).
_FINGERS = np.concatenate(
    [
        _grid((0.040, -0.010, -TIP_BELOW), (0.062, 0.010, 0.045), (2, 3, 5)),
        _grid((-0.062, -0.010, -TIP_BELOW), (-0.040, 0.010, 0.045), (2, 3, 5)),
    ]
)
_HAND = _grid((-0.10, -0.032, 0.035), (0.10, 0.032, 0.12), (9, 4, 4))
_WRIST = _grid((-0.045, -0.045, 0.13), (0.045, 0.045, 0.30), (4, 4, 6))
GRIPPER_POINTS = np.concatenate([_FINGERS, _HAND, _WRIST])
CLOSED_POINTS = np.concatenate([_grid((-0.012, -0.010, -TIP_BELOW), (0.012, 0.010, 0.045), (3, 3, 5)), _HAND, _WRIST])


def gripper_points(point: np.ndarray, orientation, closed: bool = False) -> np.ndarray:
    """Sampled points of the gripper with its grip site at ``point``; ``orientation`` is a finger
    angle (pointing down) or an end-effector frame (columns: across, finger axis, approach)."""
    rot = finger_frame(orientation) if np.ndim(orientation) == 0 else np.asarray(orientation)
    pts = CLOSED_POINTS if closed else GRIPPER_POINTS
    return point + pts[:, :1] * rot[:, 1] + pts[:, 1:2] * rot[:, 0] - pts[:, 2:3] * rot[:, 2]


def collisions(points: np.ndarray, boxes: Boxes, margin: float = 0.004) -> int:
    """How many of ``points`` lie inside any of the (inflated) oriented ``boxes``."""
    if len(boxes) == 0 or len(points) == 0:
        return 0
    return int(boxes.contains(points, margin).any(axis=1).sum())


def reach_cost(xy: np.ndarray) -> float:
    """Grows steeply where the arm nears full stretch at table height (its elbow locks near 0.75 m)."""
    d = float(np.linalg.norm(np.asarray(xy) - ROBOT_BASE_XY))
    return 0.3 * d + 8.0 * max(0.0, d - 0.68)


@dataclass(frozen=True)
class Grasp:
    point: np.ndarray
    """World position of the grip site when closed on the object."""
    theta: float
    """World angle of the fingers' closing axis."""
    kind: str
    """``band`` (the fingers close on a part narrower than the gripper), ``rim`` (on a wall) or
    ``handle`` (across a mug's handle)."""
    score: float = 0.0


def _clusters(boxes: np.ndarray, gap: float = 0.004) -> list[np.ndarray]:
    """Indices of groups of boxes (n, 2, 3) whose footprints touch (within ``gap``), transitively."""
    n = len(boxes)
    lo, hi = boxes[:, 0, :2] - gap / 2, boxes[:, 1, :2] + gap / 2
    touch = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=-1)
    label = np.arange(n)
    for _ in range(n):  # propagate the smallest label along touching pairs until stable
        new = np.where(touch, label[None], n).min(axis=1)
        if np.array_equal(new, label):
            break
        label = new
    return [np.flatnonzero(label == k) for k in np.unique(label)]


def _band_candidates(lg: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, str, np.ndarray]]:
    """(local point, local finger axis, kind, geoms in the band) for the deepest graspable band
    under the top: the whole top of a box or bottle, or separate narrow parts sticking up (the
    knob of a moka pot's lid and its handle), each a candidate of its own."""
    top, bottom = lg[:, 1, 2].max(), lg[:, 0, 2].min()
    for depth in (0.045, 0.03, 0.018):
        sel = np.flatnonzero(lg[:, 1, 2] >= top - depth)
        out = []
        for part in _clusters(lg[sel]):
            idx = sel[part]
            lo, hi = lg[idx, 0, :2].min(axis=0), lg[idx, 1, :2].max(axis=0)
            ext = hi - lo
            if ext.min() > MAX_SPAN:
                continue
            part_top = lg[idx, 1, 2].max()
            center = (lo + hi) / 2
            grip_z = max(part_top - min(depth, 0.03) + PAD_BELOW, bottom + TIP_BELOW + 0.003)
            grip_z = min(grip_z, part_top - 0.004)
            point = np.array([center[0], center[1], grip_z])
            axes = []
            if ext[0] <= MAX_SPAN:
                axes.append(np.array([1.0, 0.0]))
            if ext[1] <= MAX_SPAN:
                axes.append(np.array([0.0, 1.0]))
            if ext.max() <= 0.06 and ext.min() > 0.6 * ext.max():  # round enough to grasp from any side
                axes += [np.array([1.0, 1.0]) / math.sqrt(2), np.array([1.0, -1.0]) / math.sqrt(2)]
            out += [(point, ax, "band", idx) for ax in axes]
        if out:
            return out
    return []


def _rim(lg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre and half extents (xy) of the footprint of an object's top band, its rim."""
    rim = lg[lg[:, 1, 2] >= lg[:, 1, 2].max() - 0.008]
    lo, hi = rim[:, 0, :2].min(axis=0), rim[:, 1, :2].max(axis=0)
    return (lo + hi) / 2, (hi - lo) / 2


def _rim_candidates(lg: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, str, None]]:
    """Points on the rim of a wide, open-topped object (bowl, mug), fingers straddling the wall."""
    top, bottom = lg[:, 1, 2].max(), lg[:, 0, 2].min()
    # low objects (a plate): keep the fingertips off the table and off the plate's floor
    grip_z = max(top - PAD_ABOVE + 0.002, bottom + TIP_BELOW + 0.009)
    center, half = _rim(lg)
    offsets = (lg[:, 0, :2] + lg[:, 1, :2]) / 2 - center
    out = []
    for k in range(16):
        phi = 2 * math.pi * k / 16
        d = np.array([math.cos(phi), math.sin(phi)])
        radius = 1.0 / math.sqrt((d[0] / half[0]) ** 2 + (d[1] / half[1]) ** 2)
        # skip directions where the object reaches well past its rim (a mug's handle)
        along, across = offsets @ d, np.abs(offsets @ np.array([-d[1], d[0]]))
        if along[across < 0.02].max(initial=0.0) > radius + 0.01:
            continue
        p = center + d * (radius - 0.007)
        out.append((np.array([p[0], p[1], grip_z]), d, "rim", None))
    return out


HAND_BOTTOM = 0.035
"""The hand's underside is this far above the grip site (the fingers hang below it)."""


def handle_parts(lg: np.ndarray) -> np.ndarray:
    """Indices of the geoms standing out past the rim of a wide open-topped object (a mug's handle)."""
    center, half = _rim(lg)
    mids = (lg[:, 0, :2] + lg[:, 1, :2]) / 2 - center
    return np.flatnonzero(np.linalg.norm(mids / np.maximum(half, 1e-6), axis=1) > 1.05)


def _handle_candidates(lg: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, str, np.ndarray]]:
    """The outer end of a handle, fingers closing across its thin side, the hand's underside
    clear of the rim (so the object can be carried with the hand beside it, not above it)."""
    idx = handle_parts(lg)
    if len(idx) == 0:
        return []
    top = lg[:, 1, 2].max()
    body = np.setdiff1d(np.arange(len(lg)), idx)
    centre = (lg[body, 0, :2].min(axis=0) + lg[body, 1, :2].max(axis=0)) / 2
    mids = (lg[idx, 0, :2] + lg[idx, 1, :2]) / 2
    out = (mids - centre).mean(axis=0)
    out /= max(float(np.linalg.norm(out)), 1e-9)
    k = idx[int(np.argmax((mids - centre) @ out))]  # the outermost bar
    across = np.array([-out[1], out[0]])
    proj = lg[idx][:, :, :2] @ across
    if proj.max() - proj.min() > MAX_SPAN:
        return []
    handle_top = lg[idx, 1, 2].max()
    z = min(handle_top - 0.006, max((lg[k, 0, 2] + lg[k, 1, 2]) / 2, top - HAND_BOTTOM + 0.01))
    xy = (lg[k, 0, :2] + lg[k, 1, :2]) / 2
    return [(np.array([xy[0], xy[1], z]), across, "handle", idx)]


def plan_grasp(
    scene: Scene, name: str, avoid: tuple[str, ...] = (), then_xy: np.ndarray | None = None, kind: str | None = None
) -> Grasp | None:
    """The best-scoring grasp of object ``name`` (None when ``kind`` is asked for and it has none).

    ``then_xy``: where the object's origin will be carried; grasps that would leave the arm
    stretched there (the far rim of a bowl bound for a far plate) score worse.
    ``kind``: ``"handle"`` grasps only the handle of a mug-like object.
    """
    pos, rot = scene.pos(name), scene.mat(name)
    if kind == "handle":
        cands = _handle_candidates(scene.local_geoms(name)) if scene.upright(name) else []
        if not cands:
            return None
        world = [(pos + rot @ p, rot[:2, :2] @ ax, k, idx) for p, ax, k, idx in cands]
    elif scene.upright(name):
        lg = scene.local_geoms(name)
        cands = _band_candidates(lg) or _rim_candidates(lg)
        world = [(pos + rot @ p, rot[:2, :2] @ ax, k, idx) for p, ax, k, idx in cands]
    else:  # tipped over: grasp the middle of its world box across its narrower side
        box = scene.box(name)
        ext = box[1] - box[0]
        c = (box[0] + box[1]) / 2
        p = np.array([c[0], c[1], max(box[1, 2] - 0.02, box[0, 2] + TIP_BELOW + 0.003)])
        world = [(p, np.array([1.0, 0.0]) if ext[0] <= ext[1] else np.array([0.0, 1.0]), "band", None)]
    boxes = scene.solids(exclude=(name,) + tuple(avoid))
    best = None
    own = scene.frames(name)
    for point, ax, grip_kind, idx in world:
        theta = nearest_theta(math.atan2(ax[1], ax[0]), scene.finger_theta)
        pts = np.concatenate([gripper_points(point + np.array([0, 0, dz]), theta) for dz in (0.0, 0.04, 0.08)])
        hits = collisions(pts, boxes)
        if idx is not None and len(idx) < len(own):
            # the fingers closing on one part must also clear the object's other parts
            rest = np.setdiff1d(np.arange(len(own)), idx)
            hits += collisions(gripper_points(point, theta), Boxes(own.centers[rest], own.rots[rest], own.halves[rest]))
        score = 10.0 * hits + 0.3 * abs(wrap(theta - scene.finger_theta))
        score += reach_cost(point[:2])
        if then_xy is not None:
            score += reach_cost(np.asarray(then_xy)[:2] + point[:2] - pos[:2])
        if best is None or score < best.score:
            best = Grasp(point=point, theta=theta, kind=grip_kind, score=score)
    return best


def clear_height(
    scene: Scene, start: np.ndarray, end: np.ndarray, half_width: float, exclude: tuple[str, ...] = ()
) -> float:
    """Highest top of any geometry within ``half_width`` of the segment start-end (xy)."""
    boxes = scene.obstacles(exclude=exclude)
    if len(boxes) == 0:
        return -np.inf
    a, b = np.asarray(start[:2], dtype=float), np.asarray(end[:2], dtype=float)
    lo, hi = boxes[:, 0, :2], boxes[:, 1, :2]
    # distance from the segment to each box, sampled along the segment
    ts = np.linspace(0.0, 1.0, 21)
    pts = a[None] + ts[:, None] * (b - a)[None]
    gap = np.maximum(np.maximum(lo[None] - pts[:, None], pts[:, None] - hi[None]), 0.0)
    near = (np.linalg.norm(gap, axis=-1) < half_width).any(axis=0)
    return float(boxes[near, 1, 2].max()) if near.any() else -np.inf


def support_height(
    scene: Scene, xy: np.ndarray, below: float, exclude: tuple[str, ...] = (), half: float = 0.0
) -> float | None:
    """Top of the highest geometry under ``xy`` (or within ``half`` of it) whose top is below ``below``."""
    boxes = scene.solids(exclude=exclude)
    if len(boxes) == 0:
        return None
    offsets = [np.zeros(2)] + (
        [np.array([dx, dy]) * half for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))] if half else []
    )
    tops = boxes.tops
    best = None
    for off in offsets:
        p = np.array([xy[0] + off[0], xy[1] + off[1], 0.0])
        rel = p[None] - boxes.centers
        rel[:, 2] = 0.0
        local = np.einsum("bi,bij->bj", rel, boxes.rots)
        # upright boxes: compare in the box's own horizontal axes; ignore the vertical one
        inside = np.all((np.abs(local) <= boxes.halves + 1e-4) | (np.abs(boxes.rots[:, 2, :]) > 0.7), axis=1)
        ok = inside & (tops < below)
        if ok.any():
            h = float(tops[ok].max())
            best = h if best is None else max(best, h)
    return best
