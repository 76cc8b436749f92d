"""A read-only view of one privileged observation, in the terms the expert reasons with.

Everything here is plain geometry on :class:`PrivilegedState` (filled in by
``conflictbench.sim.capture.privileged_state``): world boxes of collision geoms, poses, joints,
region sites, and whether each goal predicate holds. No simulator is touched.
"""

from __future__ import annotations

import math

import numpy as np

from conflictbench.core import JointInfo, Observation, SiteInfo


def quat_wxyz_to_mat(q) -> np.ndarray:
    w, x, y, z = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_xyzw_to_mat(q) -> np.ndarray:
    x, y, z, w = (float(v) for v in q)
    return quat_wxyz_to_mat((w, x, y, z))


def wrap(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def finger_frame(theta: float) -> np.ndarray:
    """End-effector orientation pointing straight down with the fingers closing along ``theta``.

    Columns are the axes of robosuite's ``eef_quat`` frame in the world: its y axis is the
    fingers' closing axis and its z axis points down (LIBERO's start pose is ``theta = -pi/2``).
    """
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[-s, c, 0.0], [c, s, 0.0], [0.0, 0.0, -1.0]])


def rotvec(rot: np.ndarray) -> np.ndarray:
    """Axis-angle vector of a rotation matrix (robust near 0 and pi)."""
    cos = np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0)
    angle = math.acos(cos)
    if angle < 1e-6:
        return np.zeros(3)
    if math.pi - angle < 1e-3:
        # near pi the antisymmetric part vanishes: take the axis from the symmetric part
        axis = np.sqrt(np.clip((np.diag(rot) + 1.0) / 2.0, 0.0, None))
        k = int(np.argmax(axis))
        signs = np.sign(rot[k] + rot[:, k])
        signs[k] = 1.0
        axis = axis * np.where(signs == 0, 1.0, signs)
        return axis / np.linalg.norm(axis) * angle
    axis = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]]) / (2 * math.sin(angle))
    return axis * angle


class Boxes:
    """Oriented boxes: centres (n, 3), rotations (n, 3, 3) whose columns are the box axes, half sizes (n, 3)."""

    def __init__(self, centers: np.ndarray, rots: np.ndarray, halves: np.ndarray):
        self.centers, self.rots, self.halves = centers, rots, halves

    def __len__(self) -> int:
        return len(self.centers)

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(n_points, n_boxes) mask: which points lie inside which (inflated) boxes."""
        points = np.asarray(points, dtype=float)
        # only boxes whose bounding sphere reaches the points' bounding box can contain any of them
        reach = np.linalg.norm(self.halves + margin, axis=1)
        lo, hi = points.min(axis=0), points.max(axis=0)
        near = np.all((self.centers + reach[:, None] > lo) & (self.centers - reach[:, None] < hi), axis=1)
        out = np.zeros((len(points), len(self.centers)), dtype=bool)
        if near.any():
            out[:, near] = Boxes(self.centers[near], self.rots[near], self.halves[near])._contains(points, margin)
        return out

    def _contains(self, points: np.ndarray, margin: float) -> np.ndarray:
        n = len(self.centers)
        # one matrix product instead of a broadcast einsum: (p, 3) @ (3, 3b), minus each centre's image
        flat = points @ self.rots.transpose(1, 0, 2).reshape(3, 3 * n)
        local = flat.reshape(-1, n, 3) - np.einsum("bi,bij->bj", self.centers, self.rots)[None]
        return np.all(np.abs(local) < self.halves[None] + margin, axis=-1)

    def reach(self, axis: np.ndarray) -> np.ndarray:
        """How far each box extends from its centre along the world direction ``axis`` (unit)."""
        return np.einsum("bj,bj->b", np.abs(np.einsum("bij,i->bj", self.rots, axis)), self.halves)

    @property
    def tops(self) -> np.ndarray:
        return self.centers[:, 2] + self.reach(np.array([0.0, 0.0, 1.0]))


class Scene:
    """Geometry of the scene at one decision point."""

    def __init__(self, obs: Observation):
        if obs.privileged is None or obs.privileged.geometry is None:
            raise ValueError("the scripted expert needs privileged state (needs_privileged = True)")
        self.obs = obs
        self.priv = obs.privileged
        self.geo = obs.privileged.geometry
        self.eef = np.asarray(obs.eef_pos, dtype=float)
        self.rot = quat_xyzw_to_mat(obs.eef_quat)
        self.width = float(obs.gripper_qpos[0] - obs.gripper_qpos[1])
        """Distance between the fingers (about 0.08 open, 0 closed on nothing)."""

    # -- the gripper --------------------------------------------------------------------------
    @property
    def finger_theta(self) -> float:
        """World angle of the fingers' closing axis (defined modulo pi)."""
        return math.atan2(self.rot[1, 1], self.rot[0, 1])

    def touching(self, name: str) -> bool:
        return name in self.geo.gripper_contacts

    # -- objects and fixtures -----------------------------------------------------------------
    def pos(self, name: str) -> np.ndarray:
        return np.asarray(self.priv.body_poses[name][:3], dtype=float)

    def mat(self, name: str) -> np.ndarray:
        return quat_wxyz_to_mat(self.priv.body_poses[name][3:])

    def has(self, name: str) -> bool:
        return name in self.geo.aabb

    def box(self, name: str) -> np.ndarray:
        return np.asarray(self.geo.aabb[name], dtype=float)

    def geoms(self, name: str) -> np.ndarray:
        return np.asarray(self.geo.geom_boxes[name], dtype=float)

    def local_geoms(self, name: str) -> np.ndarray:
        return np.asarray(self.geo.local_geoms[name], dtype=float)

    def objects(self) -> list[str]:
        """Every object and fixture that has collision geometry."""
        return [n for n in self.priv.body_poses if n in self.geo.aabb]

    def obstacles(self, exclude: tuple[str, ...] = ()) -> np.ndarray:
        """World axis-aligned boxes (n, 2, 3) of every collision geom except ``exclude``'s."""
        parts = [self.geoms(n) for n in self.objects() if n not in exclude]
        return np.concatenate(parts) if parts else np.zeros((0, 2, 3))

    def frames(self, name: str) -> Boxes:
        """Oriented boxes of the collision geoms of one object, fixture or moving body."""
        part = self.geo.geom_frames[name]
        return Boxes(part.centers, part.rotations, part.half_sizes)

    def solids(self, exclude: tuple[str, ...] = ()) -> Boxes:
        """Oriented boxes of every collision geom except ``exclude``'s (exact for rotated fixtures)."""
        parts = [self.geo.geom_frames[n] for n in self.objects() if n not in exclude]
        if not parts:
            return Boxes(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
        return Boxes(*(np.concatenate([getattr(p, k) for p in parts]) for k in ("centers", "rotations", "half_sizes")))

    def upright(self, name: str) -> bool:
        return self.mat(name)[2, 2] > 0.9

    # -- sites and joints ---------------------------------------------------------------------
    def site(self, name: str) -> SiteInfo:
        return self.geo.sites[name]

    def is_site(self, name: str) -> bool:
        return name in self.geo.sites

    def joint(self, name: str) -> JointInfo:
        return self.geo.joints[name]

    def joints_of(self, name: str) -> list[str]:
        """The joints that articulate a region site or a fixture."""
        if self.is_site(name) and self.site(name).joints:
            return list(self.site(name).joints)
        return [j for j in self.geo.joints if j.startswith(name + "_")]

    def holds(self, index: int) -> bool:
        return bool(self.geo.goal_holds[index])
