"""Typed records exchanged between the simulator, policies, metrics and the store.

Only numpy is needed here: these are the types a plugin sees. Arrays follow LIBERO's units
(metres, radians, the 7-D delta end-effector action ``[dx, dy, dz, drx, dry, drz, gripper]``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

ACTION_DIM = 7
#: How the ``error`` of an episode ended by the simulator (not the policy) begins.
SIMULATOR_ERROR_PREFIX = "simulator error"
#: How the ``error`` of an episode ended by the serving infrastructure (a policy server's error
#: reply, a connection that kept failing) begins; such episodes are played again by the next run.
INFRASTRUCTURE_ERROR_PREFIX = "infrastructure error"
#: Whose failure ended an episode, decided by where it was raised (the ``error_kind`` column). ``policy``: the
#: model's own answer (an in-process policy's ``act`` raised, a served model's valid reply was NaN or the wrong
#: shape): the episode counts as failed. The others are not the model's behaviour: ``plugin`` (a post-processor
#: or prompt hook), ``client`` (a served policy's own ``encode``/``decode``), ``server`` (the policy server or
#: the connection to it), ``simulator`` (the simulator or its worker process). Such an episode is left out of
#: every measure, with its pair, and played again by the next run.
ERROR_KINDS = ("policy", "plugin", "client", "server", "simulator")
LIBERO_SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
PROMPT_CONDITIONS = ("p0", "p1")
FAMILIES = ("instruction", "grounding", "spatial", "physical")
LEVELS = ("L1", "L2", "L3", "L4")


@dataclass(frozen=True)
class ConflictCase:
    """One premise-conflict case: a base task plus an instruction whose premise cannot hold.

    ``init_states`` lists the fixed initial states in which the premise is known to be false
    (``None``: all of them); the planner pairs the case only with those.
    """

    case_id: str
    suite: str
    task_id: int
    base_instruction: str
    instruction: str
    family: str
    level: str
    factors: tuple[str, ...] = ()
    premise: str = ""
    witness: Mapping[str, Any] = field(default_factory=dict)
    status: str = "accepted"
    init_states: tuple[int, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["factors"] = list(self.factors)
        out["witness"] = dict(self.witness)
        out["init_states"] = None if self.init_states is None else list(self.init_states)
        return out


@dataclass(frozen=True)
class OrientedBoxes:
    """Boxes in the world: centres (n, 3), rotations (n, 3, 3) whose columns are the box axes, half sizes (n, 3)."""

    centers: np.ndarray
    rotations: np.ndarray
    half_sizes: np.ndarray


@dataclass(frozen=True)
class JointInfo:
    """One hinge or slide joint of the scene (a drawer, a door, a knob) at this instant."""

    qpos: float
    axis: np.ndarray
    """World direction of the joint axis (3,)."""
    anchor: np.ndarray
    """World position of the joint anchor (3,)."""
    range: np.ndarray
    """Joint limits (2,): metres for a slide, radians for a hinge."""
    body: str
    """The body the joint moves (a key of :attr:`SceneGeometry.aabb`)."""
    kind: str
    """``"slide"`` or ``"hinge"``."""


@dataclass(frozen=True)
class SiteInfo:
    """One region site of the scene (``wooden_cabinet_1_top_region``, ``plate_1_contain_region``)."""

    pos: np.ndarray
    """World position (3,)."""
    xmat: np.ndarray
    """World orientation (3, 3)."""
    size: np.ndarray
    """Half sizes (3,) in the site frame."""
    joints: tuple[str, ...]
    """The joints that articulate the region (a drawer's slide), if any."""
    parent: str | None
    """The object or fixture the region belongs to; ``None`` for a region of the table."""


@dataclass(frozen=True)
class SceneGeometry:
    """Per-step scene geometry for built-in experts. Every axis-aligned box is a (2, 3) lower/upper pair.

    Objects and fixtures are keyed by name, and so is every body moved by a scene joint
    (``wooden_cabinet_1_cabinet_top``), with the boxes of its collision geoms.
    """

    objects: tuple[str, ...]
    """The movable objects."""
    fixtures: tuple[str, ...]
    aabb: Mapping[str, np.ndarray]
    """World box around all collision geoms of an object, fixture or moving body."""
    geom_boxes: Mapping[str, np.ndarray]
    """World boxes (n, 2, 3) of each collision geom."""
    geom_frames: Mapping[str, OrientedBoxes]
    """The same geoms as oriented boxes."""
    local_aabb: Mapping[str, np.ndarray]
    """Like ``aabb``, in the frame of the object's root body (objects and fixtures only)."""
    local_geoms: Mapping[str, np.ndarray]
    """Like ``geom_boxes``, in the frame of the object's root body (objects and fixtures only)."""
    joints: Mapping[str, JointInfo]
    sites: Mapping[str, SiteInfo]
    gripper_contacts: tuple[str, ...]
    """Objects and fixtures the gripper's fingers touch."""
    goal_holds: tuple[bool, ...]
    """Whether each goal predicate holds now, by LIBERO's own predicate functions."""


@dataclass(frozen=True)
class PrivilegedState:
    """Simulator ground truth, given only to policies that declare ``needs_privileged = True``.

    Built-in experts and oracles use it; a learned policy must never ask for it.
    """

    body_poses: Mapping[str, np.ndarray]
    """Root pose of every object and fixture: ``name -> (7,)`` position + quaternion (w, x, y, z)."""
    site_positions: Mapping[str, np.ndarray]
    """World position of every named region site: ``name -> (3,)``."""
    joint_positions: Mapping[str, float]
    """Position of every articulated scene joint (drawers, doors, knobs): ``name -> qpos``."""
    goal: tuple[tuple[str, ...], ...]
    """The base task's BDDL goal predicates, e.g. ``(("on", "akita_black_bowl_1", "plate_1"),)``."""
    case: ConflictCase | None
    """The conflict case of this episode; ``None`` on a reference episode."""
    geometry: SceneGeometry | None = None
    """Collision boxes, joints, region sites, contacts and goal predicates (what the scripted expert reads)."""


@dataclass(frozen=True)
class SceneState:
    """Where things are in the scene, and nothing about the task: what a camera-free learned policy may see.

    Given to policies that declare ``needs_scene_state = True``. Unlike :class:`PrivilegedState` it holds
    no goal, no conflict case and no geometry, so a policy reading it must learn the task from the words.
    """

    body_poses: Mapping[str, np.ndarray]
    """Root pose of every object: ``name -> (7,)`` position + quaternion (w, x, y, z)."""
    site_positions: Mapping[str, np.ndarray]
    """World position of every named region of the scene (all of them, not only the task's): ``name -> (3,)``."""
    joint_positions: Mapping[str, float]
    """Position of every articulated scene joint (drawers, doors, knobs): ``name -> qpos``."""


@dataclass(frozen=True)
class Observation:
    """What a policy sees at one decision point.

    Images are exactly what LIBERO renders (upside down, uint8 HxWx3); native clients rotate
    them 180 degrees, and so must a plugin that speaks such a protocol. They are ``None`` when the
    policy does not declare ``needs_images``.
    """

    step: int
    """Number of policy actions executed so far in this episode (0 at the first query)."""
    instruction: str
    """The prompt text for this episode (after P0/P1 formatting)."""
    eef_pos: np.ndarray
    eef_quat: np.ndarray
    """End-effector orientation as robosuite reports it (x, y, z, w)."""
    gripper_qpos: np.ndarray
    state: np.ndarray
    """LIBERO's 8-D state: eef position, axis-angle of eef_quat, the two gripper joint positions."""
    agentview_image: np.ndarray | None = None
    wrist_image: np.ndarray | None = None
    joint_positions: np.ndarray | None = None
    """The seven arm joint positions."""
    joint_velocities: np.ndarray | None = None
    """The seven arm joint velocities (robosuite's ``robot0_joint_vel``)."""
    gripper_qvel: np.ndarray | None = None
    """The two gripper joint velocities (robosuite's ``robot0_gripper_qvel``)."""
    eef_mat: np.ndarray | None = None
    """The end-effector orientation as a 3x3 matrix, as the arm's controller last computed it
    (``robots[0].controller.ee_ori_mat``: what LeRobot's LIBERO env reports, not derived from ``eef_quat``)."""
    privileged: PrivilegedState | None = None
    scene: SceneState | None = None
    """Object poses, regions and scene joints, for a policy that declares ``needs_scene_state``."""
    stream: int = 0
    """Which concurrent episode this belongs to (worker slot); batched policies key state by it."""
    episode_id: str = ""
    """The episode's identity in the store (it covers the code by content)."""
    sampling_key: str = ""
    """What seeds sampling with ``step`` (:func:`rng_for`): the episode's identity by settings and versions, without
    the code's content, so that editing code that changes no action draws the same noise (an edit that changes
    actions still plays the episode again, under a new ``episode_id``). Empty: ``episode_id`` seeds."""
    suite: str = ""
    """The LIBERO suite of the episode's base task (``libero_goal``, ...): the same for a conflict and its
    reference. Native clients of per-suite checkpoints pick their normalization statistics by it."""


@dataclass(frozen=True)
class ActionContext:
    """What an action post-processor knows about the action it transforms."""

    policy: str
    suite: str
    task_id: int
    prompt: str
    case_id: str | None
    step: int
    """Index of this action in the episode (0-based)."""
    chunk_index: int
    """Index of this action inside the chunk the policy returned."""


@dataclass(eq=False)  # arrays inside: compare fields explicitly
class EpisodeRecord:
    """One closed-loop rollout, exactly as stored (one row of the episode store).

    ``eef_pos`` and ``target_pos`` hold the H+1 recorded states (after the warm-up, then after
    each of the H executed actions); ``actions`` are the H actions sent to the environment after
    post-processing and ``raw_actions`` what the policy returned for them.
    """

    # keys
    policy: str
    suite: str
    task_id: int
    init_state: int
    prompt: str
    instruction: str
    seed: int = 7
    case_id: str | None = None
    family: str | None = None
    level: str | None = None
    # outcome
    success: bool = False
    steps: int = 0
    error: str | None = None
    error_kind: str | None = None
    """One of :data:`ERROR_KINDS` where ``error`` is set (``None`` in stores written before the column: see
    :attr:`failure_kind`)."""
    sim_warnings: tuple[str, ...] = ()
    """MuJoCo's warnings during the episode, e.g. ``mjWARN_BADQACC x2`` (an unstable simulation, which
    MuJoCo resets); empty where there were none (and in stores written before the column)."""
    # process
    eef_pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    target_pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    target_names: tuple[str, ...] = ()
    actions: np.ndarray = field(default_factory=lambda: np.zeros((0, ACTION_DIM)))
    raw_actions: np.ndarray = field(default_factory=lambda: np.zeros((0, ACTION_DIM)))
    # context
    episode_id: str = ""
    conflict_suite: str | None = None
    """``name version`` of the suite the conflict case comes from (``conflictvla 2.1.0``); None for a reference (and
    in stores written before the column). Reports show the current suite's episodes by default."""
    base_instruction: str = ""
    prompt_text: str = ""
    max_steps: int = 0
    warmup_steps: int | None = None
    """No-op steps played after setting the initial state, before the first recorded state (what a replay
    must play again; ``None`` in stores written before the column)."""
    control_mode: str | None = None
    """How the arm read the actions after the warm-up, ``relative`` or ``absolute`` (what a replay must set again;
    ``None`` in stores written before the column: relative)."""
    # provenance
    conflictbench_version: str = ""
    plugin: str = ""
    plugin_version: str = ""
    code_versions: tuple[str, ...] = ()
    """``distribution==version files=DIGEST`` of all code that can change this episode (conflictbench's rollout
    packages, the policy's plugin, every plugin implementing a global per-episode hook and the conflictbench
    distributions they require; the digest is of their files' content); part of its identity. Stores written
    before the digest hold ``distribution==version``."""
    model_stack: tuple[str, ...] = ()
    """The stack a served model ran on, part of the identity: ``device=KIND`` and each distribution's
    ``name==version`` in its environment (read before the run); ``("unreported",)`` from a server that does not say;
    empty for a policy that runs no model server (and in stores written before the column)."""
    libero_version: str = ""
    robosuite_version: str = ""
    mujoco_version: str = ""
    numpy_version: str = ""
    sim_stack: tuple[str, ...] = ()
    """The rest of the stack below the policy, ``key=value``: for a policy that sees images the renderer
    (``gl_backend``, ``gl_vendor``, ``gl_renderer``, ``gl_version``) and the image libraries (``pillow``, ...);
    empty for a state-only policy and in stores written before the column. Part of the identity."""
    policy_identity: str = ""
    """What the policy declared of itself beyond its settings (``identity``, JSON, the model stack apart: a
    checkpoint's fingerprint, a server's batch shape); empty where it declared nothing and in stores written before
    the column. With ``policy_settings`` it tells variants of one policy apart (``conflictbench prune``)."""
    config_hash: str = ""
    policy_settings: str = ""
    """The policy's settings as JSON (those in its identity: not a server's address or timeouts), so that
    variants of one policy can be told apart by what differs ("" in stores written before the column)."""
    wall_time_s: float = 0.0
    """Seconds from handing the episode to a worker to its result (simulation, policy and waiting)."""
    sim_time_s: float | None = None
    """Seconds the worker spent simulating (env build, reset, warm-up, steps, capture), not waiting for
    the policy; ``None`` where not measured (stored before this column existed, or never simulated)."""
    created_at: str = ""

    @property
    def is_reference(self) -> bool:
        return self.case_id is None

    @property
    def failure_kind(self) -> str | None:
        """Whose failure ended this episode (:data:`ERROR_KINDS`), ``None`` where none did. Episodes stored
        before the ``error_kind`` column get it from their error's text, as those stores decided it."""
        if self.error is None:
            return None
        if self.error_kind:
            return self.error_kind
        if self.error.startswith(SIMULATOR_ERROR_PREFIX):
            return "simulator"
        return "server" if self.error.startswith(INFRASTRUCTURE_ERROR_PREFIX) else "policy"

    @property
    def simulator_failed(self) -> bool:
        """The environment, not the policy, ended this episode: it says nothing about the policy."""
        return self.failure_kind == "simulator"

    @property
    def infrastructure_failed(self) -> bool:
        """Something other than the policy ended this episode (a plugin, a client, a server, the simulator):
        it is left out of the measures with its pairs and played again by the next run. A policy error
        (raised, NaN, wrong shape) is different: that episode counts as failed."""
        return self.failure_kind not in (None, "policy")


@dataclass(frozen=True)
class Pair:
    """A reference and a conflict rollout by the same policy, base task, init state and prompt."""

    reference: EpisodeRecord
    conflict: EpisodeRecord
