"""Reading the simulator: observations for policies, recorded states for metrics."""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from conflictbench.core import (
    ConflictCase,
    JointInfo,
    Observation,
    OrientedBoxes,
    PrivilegedState,
    SceneGeometry,
    SceneState,
    SiteInfo,
)

from .libero_env import CAMERAS

Resolver = Callable[[], np.ndarray]

_FREE, _SLIDE, _HINGE = (
    int(k) for k in (mujoco.mjtJoint.mjJNT_FREE, mujoco.mjtJoint.mjJNT_SLIDE, mujoco.mjtJoint.mjJNT_HINGE)
)
_Geom = mujoco.mjtGeom


def _joint_bodies(model, prefix: str) -> list[int]:
    """Bodies moved by the scene joints whose names start with ``prefix``."""
    out = []
    for j in range(model.njnt):
        name = model.joint_id2name(j) or ""
        if name.startswith(prefix + "_") and model.jnt_type[j] != _FREE:
            out.append(int(model.jnt_bodyid[j]))
    return out


def target_resolver(env, name: str) -> Resolver:
    """How to read the world position of one target of the original task.

    Movable objects: their body position. A region of an articulated fixture (a drawer): the
    region's site, which rides on the moving part. A fixture with one moving part (a microwave
    door, a stove knob): that part's centre of mass. Anything else: its site or body position.
    """
    inner, model, data = env.env, env.sim.model, env.sim.data
    if name in inner.objects_dict:
        body = inner.obj_body_id[name]
        return lambda: data.body_xpos[body].copy()
    site_names = {model.site_id2name(i) for i in range(model.nsite)}
    if name in site_names:
        site = model.site_name2id(name)
        return lambda: data.site_xpos[site].copy()
    moving = _joint_bodies(model, name)
    if len(moving) == 1:
        body = moving[0]
        return lambda: data.xipos[body].copy()
    if name in inner.obj_body_id:
        body = inner.obj_body_id[name]
        return lambda: data.body_xpos[body].copy()
    raise KeyError(f"cannot locate target {name!r} in the scene")


def quat2axisangle(quat: np.ndarray) -> np.ndarray:
    """robosuite's conversion (x, y, z, w) -> axis-angle, as native LIBERO clients compute state."""
    from robosuite.utils.transform_utils import quat2axisangle as convert

    return np.asarray(convert(np.array(quat, dtype=np.float64)), dtype=np.float64)


def _owners(inner, model) -> list[str | None]:
    """The root object or fixture of every body: walk up until a body registered in ``obj_body_id``."""
    parent = np.asarray(model.body_parentid)
    root_of_body = {int(body): name for name, body in inner.obj_body_id.items()}
    owner = [None] * model.nbody
    for b in range(model.nbody):
        x = b
        while x != 0 and x not in root_of_body:
            x = int(parent[x])
        owner[b] = root_of_body.get(x)
    return owner


def _scene_joints(model) -> tuple[list, dict[str, int], set[int]]:
    """The hinge and slide joints of the scene (drawers, doors, knobs; not the robot's), their kinds and the
    bodies they move."""
    joints, kinds, moving = [], {}, set()
    for j in range(model.njnt):
        name = model.joint_id2name(j) or ""
        if model.jnt_type[j] in (_SLIDE, _HINGE) and not name.startswith(("robot0_", "gripper0_")):
            body = int(model.jnt_bodyid[j])
            joints.append((name, j, body, int(model.jnt_qposadr[j]), np.array(model.jnt_range[j], dtype=float)))
            kinds[name] = int(model.jnt_type[j])
            moving.add(body)
    return joints, kinds, moving


def _moved_with(model, moving: set[int]) -> set[int]:
    """``moving`` and every body below one of them: children of a moving body move with it."""
    parent = np.asarray(model.body_parentid)
    movers = set(moving)
    for b in range(model.nbody):
        x = b
        while x != 0:
            if x in moving:
                movers.add(b)
                break
            x = int(parent[x])
    return movers


def _half_extent(model, g: int) -> np.ndarray | None:
    """Half the size of geom ``g``'s bounding box in its own frame (None for a shape not handled)."""
    size = np.asarray(model.geom_size[g], dtype=float)
    kind = int(model.geom_type[g])
    if kind in (_Geom.mjGEOM_BOX, _Geom.mjGEOM_ELLIPSOID):
        return size[:3]
    if kind == _Geom.mjGEOM_SPHERE:
        return np.full(3, size[0])
    if kind == _Geom.mjGEOM_CAPSULE:
        return np.array([size[0], size[0], size[1] + size[0]])
    if kind == _Geom.mjGEOM_CYLINDER:
        return np.array([size[0], size[0], size[1]])
    if kind == _Geom.mjGEOM_MESH:  # its vertices' extent in the geom frame
        adr, num = model.mesh_vertadr[model.geom_dataid[g]], model.mesh_vertnum[model.geom_dataid[g]]
        return np.abs(np.asarray(model.mesh_vert[adr : adr + num])).max(axis=0)
    return None


_UNIT_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


def _collision_boxes(model, owner: list[str | None]) -> tuple[list[tuple[int, int]], list[np.ndarray]]:
    """The scene's collision geoms (with their bodies), each as the 8 corners of its bounding box in the geom
    frame."""
    geoms, corners = [], []
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if owner[b] is None or not (model.geom_contype[g] or model.geom_conaffinity[g]):
            continue
        half = _half_extent(model, g)
        if half is None:
            continue
        geoms.append((g, b))
        corners.append(_UNIT_CORNERS * half)
    return geoms, corners


def _object_sites(inner, model) -> list[tuple]:
    """The objects' sites present in the model: name, id, size, joints and parent."""
    site_names = {model.site_id2name(i) for i in range(model.nsite)}
    sites = []
    for name, site in inner.object_sites_dict.items():
        if name in site_names:
            size = np.asarray(site.size if site.size is not None else np.zeros(3), dtype=float)
            sites.append((name, model.site_name2id(name), size, tuple(site.joints or ()), site.parent_name))
    return sites


class _SceneStatic:
    """Facts about one MuJoCo model that never change during an episode (computed once per model)."""

    def __init__(self, env):
        inner, model = env.env, env.sim.model
        self.model = model  # held so that a new model (every reset rebuilds it) is never mistaken for this one
        owner = _owners(inner, model)
        self.body_names = [model.body_id2name(b) for b in range(model.nbody)]
        self.joints, self.joint_kind, moving = _scene_joints(model)
        geoms, corners = _collision_boxes(model, owner)
        self.geom_ids = np.array([g for g, _ in geoms], dtype=int)
        self.geom_body = np.array([b for _, b in geoms], dtype=int)
        self.corners = np.array(corners).reshape(-1, 8, 3)
        geom_owner = np.array([owner[b] for b in self.geom_body], dtype=object)
        self.owner_mask = {name: geom_owner == name for name in inner.obj_body_id}
        self.mover_bodies = sorted(_moved_with(model, moving))
        self.owner = owner
        self.obj_body_id = dict(inner.obj_body_id)
        self.movable = tuple(inner.objects_dict)
        self.fixtures = tuple(inner.fixtures_dict)
        self.sites = _object_sites(inner, model)
        finger_bodies = {b for b in range(model.nbody) if (self.body_names[b] or "").startswith("gripper0_")}
        self.finger_geom = np.array([int(model.geom_bodyid[g]) in finger_bodies for g in range(model.ngeom)])
        self.geom_root = [owner[int(model.geom_bodyid[g])] for g in range(model.ngeom)]


_STATIC: list[_SceneStatic] = []


def _static_for(env) -> _SceneStatic:
    if not _STATIC or _STATIC[0].model is not env.sim.model:
        _STATIC[:] = [_SceneStatic(env)]
    return _STATIC[0]


def _geometry(env, st: _SceneStatic, goal) -> SceneGeometry:
    """The scene's geometry now (see :class:`SceneGeometry` for what each part holds)."""
    data = env.sim.data
    xpos = np.asarray(data.geom_xpos)[st.geom_ids]
    xmat = np.asarray(data.geom_xmat)[st.geom_ids].reshape(-1, 3, 3)
    points = xpos[:, None, :] + np.einsum("gij,gkj->gki", xmat, st.corners)
    boxes = np.stack([points.min(axis=1), points.max(axis=1)], axis=1)
    aabb, geom_boxes, geom_frames, local, local_geoms = {}, {}, {}, {}, {}

    def add(name: str, sel: np.ndarray) -> None:
        geom_boxes[name] = boxes[sel]
        geom_frames[name] = OrientedBoxes(xpos[sel].copy(), xmat[sel].copy(), st.corners[sel, -1].copy())
        aabb[name] = np.stack([boxes[sel, 0].min(axis=0), boxes[sel, 1].max(axis=0)])

    for name, body in st.obj_body_id.items():
        sel = st.owner_mask[name]
        if not sel.any():
            continue
        add(name, sel)
        rot = np.asarray(data.body_xmat[body]).reshape(3, 3)
        pts = (points[sel] - data.body_xpos[body]) @ rot
        local_geoms[name] = np.stack([pts.min(axis=1), pts.max(axis=1)], axis=1)
        local[name] = np.stack([local_geoms[name][:, 0].min(axis=0), local_geoms[name][:, 1].max(axis=0)])
    for body in st.mover_bodies:
        sel = st.geom_body == body
        if sel.any():
            add(st.body_names[body], sel)
    joints = {
        name: JointInfo(
            qpos=float(data.qpos[adr]),
            axis=np.array(data.xaxis[j]),
            anchor=np.array(data.xanchor[j]),
            range=rng.copy(),
            body=st.body_names[body],
            kind="slide" if st.joint_kind[name] == _SLIDE else "hinge",
        )
        for name, j, body, adr, rng in st.joints
    }
    sites = {
        name: SiteInfo(
            pos=np.array(data.site_xpos[sid]),
            xmat=np.array(data.site_xmat[sid]).reshape(3, 3),
            size=size.copy(),
            joints=sjoints,
            parent=parent,
        )
        for name, sid, size, sjoints, parent in st.sites
    }
    touching = set()
    for i in range(data.ncon):
        c = data.contact[i]
        g1, g2 = int(c.geom1), int(c.geom2)
        if st.finger_geom[g1] and st.geom_root[g2]:
            touching.add(st.geom_root[g2])
        elif st.finger_geom[g2] and st.geom_root[g1]:
            touching.add(st.geom_root[g1])
    holds = tuple(bool(env.env._eval_predicate(tuple(p))) for p in goal)
    return SceneGeometry(
        objects=st.movable,
        fixtures=st.fixtures,
        aabb=aabb,
        geom_boxes=geom_boxes,
        geom_frames=geom_frames,
        local_aabb=local,
        local_geoms=local_geoms,
        joints=joints,
        sites=sites,
        gripper_contacts=tuple(sorted(touching)),
        goal_holds=holds,
    )


def scene_state(env) -> SceneState:
    """Object poses, every region's position and every scene joint's position: no goal, no case, no geometry."""
    inner, data = env.env, env.sim.data
    st = _static_for(env)
    poses = {
        name: np.concatenate([data.body_xpos[body], data.body_xquat[body]]).copy()
        for name, body in inner.obj_body_id.items()
    }
    sites = {name: np.array(data.site_xpos[sid]) for name, sid, *_ in st.sites}
    joints = {name: float(data.qpos[adr]) for name, _, _, adr, _ in st.joints}
    return SceneState(body_poses=poses, site_positions=sites, joint_positions=joints)


def privileged_state(env, goal: tuple[tuple[str, ...], ...], case: ConflictCase | None) -> PrivilegedState:
    """The scene state (read once, by :func:`scene_state`) with the task's goal, the case and the geometry."""
    scene = scene_state(env)
    return PrivilegedState(
        body_poses=scene.body_poses,
        site_positions=scene.site_positions,
        joint_positions=scene.joint_positions,
        goal=goal,
        case=case,
        geometry=_geometry(env, _static_for(env), goal),
    )


def make_observation(
    raw_obs: dict,
    *,
    step: int,
    instruction: str,
    stream: int,
    episode_id: str,
    suite: str,
    images: bool,
    privileged: PrivilegedState | None,
    scene: SceneState | None = None,
    sampling_key: str = "",
    eef_mat: np.ndarray | None = None,
) -> Observation:
    """The policy's view: robosuite's own observation values, exactly as a native client gets them.

    ``eef_mat`` is the controller's end-effector orientation matrix (:func:`controller_eef_mat`), which robosuite's
    observation does not hold."""
    eef_pos = np.asarray(raw_obs["robot0_eef_pos"], dtype=np.float64).copy()
    eef_quat = np.asarray(raw_obs["robot0_eef_quat"], dtype=np.float64).copy()
    gripper = np.asarray(raw_obs["robot0_gripper_qpos"], dtype=np.float64).copy()
    agent = wrist = None
    if images:
        agent, wrist = (np.array(raw_obs[f"{camera}_image"]) for camera in CAMERAS)
    return Observation(
        step=step,
        instruction=instruction,
        eef_pos=eef_pos,
        eef_quat=eef_quat,
        gripper_qpos=gripper,
        state=np.concatenate([eef_pos, quat2axisangle(eef_quat), gripper]),
        agentview_image=agent,
        wrist_image=wrist,
        joint_positions=np.asarray(raw_obs["robot0_joint_pos"], dtype=np.float64).copy(),
        joint_velocities=_optional(raw_obs, "robot0_joint_vel"),
        gripper_qvel=_optional(raw_obs, "robot0_gripper_qvel"),
        eef_mat=None if eef_mat is None else np.array(eef_mat, dtype=np.float64),
        privileged=privileged,
        scene=scene,
        stream=stream,
        episode_id=episode_id,
        sampling_key=sampling_key,
        suite=suite,
    )


def _optional(raw_obs: dict, key: str) -> np.ndarray | None:
    """A float64 copy of ``raw_obs[key]``; None where robosuite's observation does not hold it."""
    value = raw_obs.get(key)
    return None if value is None else np.asarray(value, dtype=np.float64).copy()


def controller_eef_mat(env) -> np.ndarray:
    """The arm controller's end-effector orientation matrix (3, 3), as the controller last updated it (at its last
    control sub-step): what LeRobot's LIBERO env reports as ``robot_state/eef/mat`` (``libero.py``'s
    ``_format_raw_obs`` reads ``robots[0].controller.ee_ori_mat``)."""
    return np.array(env.env.robots[0].controller.ee_ori_mat, dtype=np.float64)
