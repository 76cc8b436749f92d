"""From one BDDL goal predicate to the skill that achieves it."""

from __future__ import annotations

import numpy as np

from conflictbench.core import SiteInfo

from . import articulated, enclosed
from .grasp import reach_cost
from .pick_place import is_flat, pick, place, push
from .primitives import Context, Skill
from .scene import Scene

PUSH_FLAT = True
FREE_MARGIN = 0.015
"""Clearance kept between a placed object and its neighbours (they get nudged on the way)."""


def achieve(ctx: Context, goal: tuple[tuple[str, ...], ...], index: int) -> Skill:
    pred = goal[index]
    kind = pred[0]
    if kind in ("on", "in"):
        return (yield from _put(ctx, goal, index))
    if kind in ("open", "close"):
        return (yield from articulated.set_open(ctx, pred[1], opened=kind == "open"))
    if kind in ("turnon", "turnoff"):
        return (yield from articulated.turn(ctx, pred[1], on=kind == "turnon"))
    ctx.notes.append(f"no skill for {kind}")
    return False


def _slot(scene: Scene, goal: tuple[tuple[str, ...], ...], index: int) -> np.ndarray:
    """Where the object's body origin should go (xy) to satisfy ``goal[index]``.

    Several objects bound for the same small region (two moka pots on one burner) get
    side-by-side slots along the region's longer free axis instead of all aiming at its centre.
    """
    _, obj, target = goal[index]
    if not scene.is_site(target):
        return scene.pos(target)[:2].copy()
    site = scene.site(target)
    center = site.pos[:2].copy()
    sharing = [i for i, p in enumerate(goal) if p[0] in ("on", "in") and len(p) == 3 and p[2] == target]
    if len(sharing) < 2:
        return center if site.parent else _free_spot(scene, obj, site)
    half = np.abs(site.xmat @ site.size)[:2]
    k = sharing.index(index)
    n = len(sharing)
    # objects' widths along x and y: put the slots along the axis where they are narrower relative to the region
    widths = np.array([scene.box(goal[i][1])[1, :2] - scene.box(goal[i][1])[0, :2] for i in sharing])
    axis = int(np.argmin(widths.max(axis=0) / np.maximum(half, 1e-6)))
    span = min(half[axis] * 0.55, widths[:, axis].max() * 0.55)
    offsets = np.linspace(-span, span, n)
    center[axis] += offsets[k]
    return center


def _free_spot(scene: Scene, obj: str, site: SiteInfo) -> np.ndarray:
    """The point of a table region, nearest its centre, where ``obj`` would touch no other object."""
    half = np.abs(site.xmat @ site.size)[:2] * 0.7
    lg = scene.local_geoms(obj)
    radius = float(np.max(lg[:, 1, :2].max(axis=0) - lg[:, 0, :2].min(axis=0)) / 2)
    others = tuple(n for n in scene.objects() if n not in scene.geo.objects or n == obj)
    best, best_cost = site.pos[:2].copy(), np.inf
    for fx in np.linspace(-1.0, 1.0, 5):
        for fy in np.linspace(-1.0, 1.0, 5):
            c = site.pos[:2] + half * np.array([fx, fy])
            hits = _overlaps(scene, obj, c, radius + FREE_MARGIN, others)
            cost = hits + float(np.linalg.norm(c - site.pos[:2]))
            if cost < best_cost:
                best, best_cost = c, cost
    return best


def _overlaps(scene: Scene, obj: str, xy: np.ndarray, radius: float, exclude: tuple[str, ...]) -> int:
    boxes = scene.solids(exclude=exclude)
    if len(boxes) == 0:
        return 0
    rel = np.array([xy[0], xy[1], 0.0])[None] - boxes.centers
    rel[:, 2] = 0.0
    local = np.abs(np.einsum("bi,bij->bj", rel, boxes.rots))
    gap = np.maximum(local - boxes.halves, 0.0)
    gap[np.abs(boxes.rots[:, 2, :]) > 0.7] = 0.0
    return int((np.linalg.norm(gap, axis=1) < radius).sum())


def _in_way(s: Scene, obj: str, sweep: np.ndarray, margin: float = 0.07) -> bool:
    """Whether the gripper, reaching for ``obj``, would meet the space a drawer opens into."""
    box = s.box(obj)
    return bool(
        np.all(box[0, :2] - margin < sweep[1, :2])
        and np.all(box[1, :2] + margin > sweep[0, :2])
        and box[1, 2] < sweep[1, 2]
    )


def _staging_spot(s: Scene, obj: str, sweep: np.ndarray) -> np.ndarray:
    """A free table spot near ``obj``, clear of the drawer's way and within easy reach."""
    lg = s.local_geoms(obj)
    radius = float(np.max(lg[:, 1, :2].max(axis=0) - lg[:, 0, :2].min(axis=0)) / 2)
    here = s.pos(obj)[:2]
    best, best_cost = here, np.inf
    for x in np.arange(-0.30, 0.11, 0.03):
        for y in np.arange(-0.30, 0.31, 0.03):
            c = np.array([x, y])
            if _in_way_at(c, radius, sweep) or reach_cost(c) > 0.3 * 0.68:
                continue
            hits = _overlaps(s, obj, c, radius + 0.02, (obj,))
            cost = 10 * hits + float(np.linalg.norm(c - here))
            if cost < best_cost:
                best, best_cost = c, cost
    return best


def _in_way_at(xy: np.ndarray, radius: float, sweep: np.ndarray, margin: float = 0.08) -> bool:
    return bool(np.all(xy - radius - margin < sweep[1, :2]) and np.all(xy + radius + margin > sweep[0, :2]))


def _put(ctx: Context, goal: tuple[tuple[str, ...], ...], index: int) -> Skill:
    _, obj, target = goal[index]
    s = ctx.scene
    if s.is_site(target) and s.site(target).joints:
        sweep = articulated.opening_sweep(s, target)
        if sweep is not None and ctx.held is None and _in_way(s, obj, sweep):
            # the drawer would open over the object: set it aside first
            spot = _staging_spot(s, obj, sweep)
            if (yield from pick(ctx, obj, then_xy=spot)):
                yield from place(ctx, obj, spot)
        container_open = yield from articulated.ensure_open(ctx, target)
        if not container_open:
            return False
    way_in = enclosed.way_in(s, obj, target) if ctx.held is None and s.is_site(target) else None
    if way_in is not None:
        return (yield from enclosed.insert(ctx, obj, way_in))
    if ctx.held is None and is_flat(s, obj) and s.is_site(target) and not s.site(target).parent and PUSH_FLAT:
        return (yield from push(ctx, obj, lambda sc: _slot(sc, goal, index)))
    if ctx.held != obj:
        ok = yield from pick(ctx, obj, then_xy=lambda sc: _slot(sc, goal, index))
        if not ok:
            return False
    return (yield from place(ctx, obj, lambda sc: _slot(sc, goal, index)))
