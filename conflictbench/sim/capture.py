"""Reading the simulator: observations for policies, recorded states for metrics."""

from __future__ import annotations

from typing import Callable

import numpy as np

from conflictbench.core import ConflictCase, Observation, PrivilegedState

from .libero_env import CAMERAS

Resolver = Callable[[], np.ndarray]


def _joint_bodies(model, prefix: str) -> list[int]:
    """Bodies moved by the scene joints whose names start with ``prefix``."""
    out = []
    for j in range(model.njnt):
        name = model.joint_id2name(j) or ""
        if name.startswith(prefix + "_") and model.jnt_type[j] != 0:  # 0 = free joint
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


def privileged_state(env, goal: tuple[tuple[str, ...], ...], case: ConflictCase | None) -> PrivilegedState:
    inner, model, data = env.env, env.sim.model, env.sim.data
    poses = {}
    for name, body in inner.obj_body_id.items():
        poses[name] = np.concatenate([data.body_xpos[body], data.body_xquat[body]]).copy()
    sites = {name: data.site_xpos[model.site_name2id(name)].copy() for name in inner.object_sites_dict
             if name in {model.site_id2name(i) for i in range(model.nsite)}}
    joints = {}
    for j in range(model.njnt):
        jname = model.joint_id2name(j) or ""
        if model.jnt_type[j] != 0 and not jname.startswith(("robot0_", "gripper0_")):
            joints[jname] = float(data.qpos[model.jnt_qposadr[j]])
    return PrivilegedState(body_poses=poses, site_positions=sites, joint_positions=joints, goal=goal, case=case)


def make_observation(raw_obs: dict, *, step: int, instruction: str, stream: int, images: bool,
                     privileged: PrivilegedState | None) -> Observation:
    """The policy's view: robosuite's own observation values, exactly as a native client gets them."""
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
        privileged=privileged,
        stream=stream,
    )
