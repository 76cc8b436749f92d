"""The learned subject as a policy: instruction words + where things are -> actions, in NumPy."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from conflictbench.core import Observation, UserError, rng_for

from ..scripted import ScriptedConfig
from .features import Entities, Vocabulary, arm_numbers, entity_numbers
from .model import Inputs, SubjectNetwork

GRIPPER_SEED = 0x5B1EC7
"""Keeps the gripper's draws apart from any other randomness derived from the same episode and step."""
SHIPPED = "subject.npz"
"""The weights that ship with the package (``conflictbench train-subject`` makes them again)."""


@dataclass
class SubjectConfig:
    weights: str | None = None
    """A ``.npz`` written by ``conflictbench train-subject``; ``null``: the weights shipped with the package."""
    execute: int = 1
    """Actions executed of each predicted chunk before the subject looks again (1 to the chunk's length)."""
    gripper_lead: int = 3
    """Steps ahead whose predicted gripper command is executed now (0 to the chunk's length - 1)."""
    sample_gripper: bool = True
    """Open or close the gripper by a draw from its predicted probability (from the episode and step, so a
    rollout is reproducible); false: whichever is likelier. See ``model.decode``."""
    seed: int = 0
    """Mixed into the gripper's draws (another seed: another sample of the same policy)."""


def _dry_run_observation() -> Observation:
    from conflictbench.core import SceneState

    scene = SceneState(
        body_poses={"plate_1": np.array([0.0, 0.0, 0.9, 1, 0, 0, 0])}, site_positions={}, joint_positions={}
    )
    return Observation(
        step=0,
        instruction="put the bowl on the plate",
        eef_pos=np.array([0.0, 0.0, 1.1]),
        eef_quat=np.array([1.0, 0.0, 0.0, 0.0]),
        gripper_qpos=np.array([0.04, -0.04]),
        state=np.zeros(8),
        scene=scene,
        episode_id="dry-run",
    )


def shipped_weights() -> Path:
    return Path(str(resources.files(__package__).joinpath(SHIPPED)))


class SubjectPolicy:
    """A small transformer trained by behaviour cloning on the scripted expert's demonstrations.

    It sees the instruction, the arm's state and every object's pose, region's position and scene
    joint's position (``needs_scene_state``), and nothing of the task: no goal, no case, no expert.
    Reproducible: the same observation (its episode and step included) gives the same action.
    """

    needs_images = False
    needs_scene_state = True
    max_steps = ScriptedConfig().max_steps  # it moves at the expert's pace, so it gets the expert's budget

    def __init__(self, cfg: SubjectConfig | None = None):
        self.cfg = cfg or SubjectConfig()
        path = Path(self.cfg.weights).expanduser() if self.cfg.weights else shipped_weights()
        if not path.is_file():
            raise UserError(f"no subject weights at {path} (make them with `conflictbench train-subject`)")
        try:
            self.network, words = SubjectNetwork.load(path)
            self.vocabulary = Vocabulary(words)
            self.positions = int(self.network.config["positions"])
            self.act_batch([_dry_run_observation()])  # a file missing a tensor fails here, not in every episode
        except Exception as exc:
            raise UserError(f"{path} is not a subject's weights file: {type(exc).__name__}: {exc}") from None
        if not 1 <= self.cfg.execute <= self.network.chunk:
            raise UserError(f"model.execute must be between 1 and {self.network.chunk}, got {self.cfg.execute}")
        if not 0 <= self.cfg.gripper_lead < self.network.chunk:
            raise UserError(
                f"model.gripper_lead must be between 0 and {self.network.chunk - 1}, got {self.cfg.gripper_lead}"
            )
        self.identity = {"weights_sha256": hashlib.sha256(path.read_bytes()).hexdigest()[:16]}

    def reset(self, instruction: str) -> None:
        """Nothing: the subject keeps no memory between its decisions."""

    def act(self, observation: Observation) -> np.ndarray:
        return self.act_batch([observation])[0]

    def act_batch(self, observations: list[Observation]) -> list[np.ndarray]:
        # One observation at a time: padded to a batch's longest, the arithmetic (and so a near-tie between two
        # bins) would depend on which episodes happen to share the batch.
        lead, execute = self.cfg.gripper_lead, self.cfg.execute
        return [self.network(self.inputs(o), lead, self.draws(o))[0][:execute] for o in observations]

    def draws(self, observation: Observation) -> np.ndarray | None:
        """The gripper's uniform draws for this decision: from its episode and step, never call order."""
        if not self.cfg.sample_gripper:
            return None
        if not observation.episode_id:
            raise UserError(
                "the subject draws its gripper from the episode and step, and this observation names no episode "
                "(observation.episode_id is empty): set it, or model.sample_gripper=false"
            )
        return rng_for(observation, GRIPPER_SEED, self.cfg.seed).random((1, self.network.chunk))

    def inputs(self, observation: Observation) -> Inputs:
        """One observation as a batch of one (the subject never pads one episode's frame to another's)."""
        scene = observation.scene
        if scene is None:
            raise UserError("the subject needs the scene state (needs_scene_state); none was given")
        entities = Entities.of(scene)
        # float32 first, as the demonstrations were recorded: training and acting compute the same numbers
        eef = np.asarray(observation.eef_pos, dtype=np.float32)
        quat, fingers = np.asarray(observation.eef_quat, np.float32), np.asarray(observation.gripper_qpos, np.float32)
        return Inputs(
            text=self.vocabulary.ids(observation.instruction)[None, : self.positions],
            names=entities.name_ids(self.vocabulary)[None],
            kinds=entities.kinds()[None],
            entities=entity_numbers(*entities.arrays(scene, np.float32), eef)[None],
            arm=arm_numbers(eef, quat, fingers)[None],
        )
