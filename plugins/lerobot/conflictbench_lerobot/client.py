"""Any LeRobot policy as conflictbench sees it: LeRobot's LIBERO env on our simulator, LeRobot on the server.

``conflictbench model=lerobot model.checkpoint=DIR`` starts our server (``conflictbench-serve lerobot``) for a folder
LeRobot's ``save_pretrained`` wrote, in the model environment (``scripts/setup.sh --models lerobot``), and plays it
as ``lerobot-eval --env.type=libero`` would: 360-pixel renders of both cameras, LeRobot's 10 settle steps, relative
control (or absolute), LeRobot's per-suite step budget, and at every step the raw observation LeRobot's env builds,
sent to the server, where LeRobot's own processors and ``select_action`` turn it into one action.
``model.server=ws://HOST:PORT model.checkpoint=NAME`` plays against a running server of ours.

The settings ``lerobot-eval`` takes from its command line rather than the checkpoint are ``model.*`` settings with
its defaults, and part of every episode's identity (README, "Settings").
"""

from __future__ import annotations

import functools
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from conflictbench import (
    HostedConfig,
    HostedPolicy,
    InfrastructureError,
    Observation,
    UserError,
    hookimpl,
    published_results,
    sampling_seed,
)
from conflictbench.hosting.openpi import OpenpiTransport

from .checkpoints import SUPPORTED_TYPES, CheckpointError, check_checkpoint, fingerprint
from .protocol import DEFAULT_CAMERA_NAMES, NOISE_SEED_LIMIT, ReplyError, reply_action, request
from .server import SERVED

#: lerobot-eval's step budget per LIBERO suite (``lerobot/envs/libero.py``, ``TASK_SUITE_MAX_STEPS``), counted
#: after the settle steps.
MAX_STEPS = {"libero_spatial": 280, "libero_object": 280, "libero_goal": 300, "libero_10": 520, "libero_90": 400}
CONTROL_MODES = ("relative", "absolute")


@dataclass
class LeRobotConfig(HostedConfig):
    """Settings of ``lerobot`` (``model.<field>=value``; the shared ones are :class:`conflictbench.HostedConfig`'s).

    ``model.max_steps`` is lerobot-eval's ``--env.episode_length`` (0: its budget per suite, 280/280/300/520)."""

    minimums: ClassVar = {**HostedConfig.minimums, "render_size": 1, "num_steps_wait": 0, "n_action_steps": 0}
    # The two maps count as what they mean (the policy's identity holds them parsed), not as typed: "" and "{}"
    # are the same rename_map. max_batch counts as 1 there: the server runs one step a call, whatever it is.
    identity_exempt: ClassVar[tuple[str, ...]] = (*HostedConfig.identity_exempt, "camera_name_mapping", "rename_map")

    render_size: int = 360
    """The cameras' width and height (``--env.observation_height`` / ``_width``; the gym class alone renders 256)."""
    control_mode: str = "relative"
    """``--env.control_mode``: ``relative`` (OSC deltas) or ``absolute`` (a target pose; must match the checkpoint)."""
    num_steps_wait: int = 10
    """No-op settle steps after the initial state (``LiberoEnv.num_steps_wait``, not a lerobot-eval setting)."""
    camera_name_mapping: str = ""
    """``--env.camera_name_mapping`` as JSON, robosuite camera -> LeRobot name; empty: ``image`` and ``image2``."""
    rename_map: str = ""
    """``--rename_map`` as JSON, observation key -> the checkpoint's key; empty: none."""
    n_action_steps: int = 0
    """``--policy.n_action_steps``: actions executed of each chunk; 0: the checkpoint's own."""


def _names(text: str, setting: str, default: dict[str, str]) -> dict[str, str]:
    if not text:
        return dict(default)
    try:
        value = json.loads(text)
    except ValueError as error:
        raise UserError(f"model.{setting} must be a JSON map of names, got {text!r} ({error})") from None
    if not isinstance(value, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        raise UserError(f"model.{setting} must be a JSON map of names to names, got {text!r}")
    return value


class LeRobotPolicy(HostedPolicy):
    """lerobot-eval's LIBERO episode: the raw observation every step, one action back (LeRobot keeps the queue)."""

    served = SERVED
    transport = OpenpiTransport
    default_max_steps = MAX_STEPS
    checkpoint_errors = (CheckpointError,)
    fingerprint = staticmethod(fingerprint)

    def __init__(self, name: str, cfg: LeRobotConfig, checkpoint: Path | None = None, python: Path | None = None):
        self.camera_names = camera_names(cfg)
        self.rename_map = _names(cfg.rename_map, "rename_map", {})
        self.image_size = cfg.render_size
        self.warmup_steps = cfg.num_steps_wait
        self.control_mode = cfg.control_mode
        super().__init__(name, cfg, checkpoint, python)
        self.identity = {**self.identity, "max_batch": 1, "camera_names": self.camera_names,
                         "rename_map": self.rename_map}  # fmt: skip

    @classmethod
    def load(cls, name: str, cfg: LeRobotConfig) -> LeRobotPolicy:
        if cfg.control_mode not in CONTROL_MODES:
            raise UserError(f"model.control_mode must be relative or absolute, got {cfg.control_mode!r}")
        names, renames = camera_names(cfg), _names(cfg.rename_map, "rename_map", {})
        kind = ""
        if cfg.checkpoint and not cfg.server:  # what LIBERO gives against what it takes, before anything starts
            try:
                kind = check_checkpoint(Path(cfg.checkpoint).expanduser(), names, renames)
            except CheckpointError as exc:
                raise UserError(str(exc)) from None
        policy = super().load(name, cfg)
        announce(kind or str(policy.metadata.get("policy_type", "unknown")), cfg.server or str(policy.checkpoint))
        return policy

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None or observation.wrist_image is None:
            raise UserError(f"{self.name} needs both camera images")
        missing = [n for n in ("eef_mat", "gripper_qvel", "joint_positions", "joint_velocities") if
                   getattr(observation, n) is None]  # fmt: skip
        if missing:
            raise InfrastructureError(f"the simulator's observation lacks {', '.join(missing)}")
        state = {
            "robot_state/eef/pos": observation.eef_pos,
            "robot_state/eef/quat": observation.eef_quat,
            "robot_state/eef/mat": observation.eef_mat,
            "robot_state/gripper/qpos": observation.gripper_qpos,
            "robot_state/gripper/qvel": observation.gripper_qvel,
            "robot_state/joints/pos": observation.joint_positions,
            "robot_state/joints/vel": observation.joint_velocities,
        }
        return request(
            (observation.agentview_image, observation.wrist_image),
            {key: np.asarray(value, dtype=np.float64) for key, value in state.items()},
            observation.instruction,
            episode=observation.episode_id,
            step=observation.step,
            seed=sampling_seed(observation) % NOISE_SEED_LIMIT,
            camera_names=self.camera_names,
            rename_map=self.rename_map,
            n_action_steps=self.cfg.n_action_steps,
        )

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        try:
            return reply_action(reply)
        except ReplyError as exc:
            raise InfrastructureError(f"{self.cfg.server or 'the lerobot server'} answered no action: {exc}") from None


def camera_names(cfg: LeRobotConfig) -> dict[str, str]:
    """robosuite camera -> LeRobot name, for both of LIBERO's cameras."""
    names = _names(cfg.camera_name_mapping, "camera_name_mapping", DEFAULT_CAMERA_NAMES)
    if set(names) != set(DEFAULT_CAMERA_NAMES):
        raise UserError(
            f"model.camera_name_mapping must name LIBERO's two cameras ({', '.join(DEFAULT_CAMERA_NAMES)}), "
            f"got {', '.join(names) or 'none'}"
        )
    return names


def announce(kind: str, where: str) -> None:
    """One line naming the checkpoint's policy type; a warning where that type is not one this plugin is tested
    with."""
    print(f"conflictbench: model=lerobot plays a LeRobot {kind} policy ({where})", file=sys.stderr)
    if kind not in SUPPORTED_TYPES:
        print(
            f"conflictbench: warning: untested policy type {kind} (tested: {', '.join(SUPPORTED_TYPES)}); LeRobot "
            "loads it, and its results are what LeRobot's code does with it",
            file=sys.stderr,
        )


def load(name: str, cfg: LeRobotConfig) -> LeRobotPolicy:
    """The policy for ``model=lerobot``: connected to ``cfg.server``, or ready to start a server for
    ``cfg.checkpoint``."""
    return LeRobotPolicy.load(name, cfg)


@hookimpl
def conflictbench_register_policies(register):
    register("lerobot", load=functools.partial(load, "lerobot"), config=LeRobotConfig)


#: LeRobot's published LIBERO results for the types this plugin adds (published.toml).
conflictbench_register_published_results = published_results(__package__)
