"""Demonstrations for the learned subject: the scripted expert, its view and its actions kept step by step, only
successful episodes written (:mod:`conflictbench.sim.demonstrations` plays it through the normal runner).

The expert's actions are the labels; what the arm executes may carry Gaussian noise (DART: the expert then
shows how to come back from states a learner will drift into). The noise is drawn from the episode and step
(``rng_for``), so a recording is reproducible however the episodes are scheduled.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from conflictbench.core import EpisodeRecord, Observation, rng_for

from ..scripted import ScriptedConfig, ScriptedPolicy
from .features import Entities

NOISE_SEED = 18
FAILED = "failed.txt"
"""Episodes the expert did not succeed in, one name a line, next to the demonstrations."""
MANIFEST = "recording.json"
"""How the demonstrations next to it were recorded; a resumed recording must use the same."""


def demonstration_name(suite: str, task_id: int, init_state: int) -> str:
    """A demonstration's file stem, and its line in the failed list."""
    return f"{suite}-{task_id:02d}-{init_state:03d}"


@dataclass
class Recording:
    """One episode's frames while it is being played."""

    instruction: str
    entities: Entities
    frames: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def add(self, **arrays: np.ndarray) -> None:
        for key, value in arrays.items():
            self.frames.setdefault(key, []).append(np.asarray(value, dtype=np.float32))


class RecordingExpert:
    """The scripted expert, with noise on what it executes and a recording of what it saw and chose."""

    needs_images = False
    needs_privileged = True
    needs_scene_state = True

    def __init__(self, out: Path, noise: float, cfg: ScriptedConfig | None = None):
        self.expert = ScriptedPolicy(cfg)
        self.max_steps = self.expert.max_steps
        self.out, self.noise = Path(out), float(noise)
        self.out.mkdir(parents=True, exist_ok=True)
        self._recordings: dict[str, Recording] = {}
        self.written = 0

    def reset(self, instruction: str) -> None:
        """Nothing: each episode's recording starts at its first observation."""

    def act(self, observation: Observation) -> np.ndarray:
        label = np.asarray(self.expert.act(observation), dtype=np.float64)
        scene = observation.scene
        recording = self._recordings.get(observation.episode_id)
        if recording is None or observation.step == 0:
            recording = Recording(observation.instruction, Entities.of(scene))
            self._recordings[observation.episode_id] = recording
        executed = label.copy()
        if self.noise > 0:
            rng = rng_for(observation, NOISE_SEED)
            executed[:6] = np.clip(executed[:6] + rng.normal(0.0, self.noise, size=6), -1.0, 1.0)
        object_poses, region_positions, joint_positions = recording.entities.arrays(scene)
        recording.add(
            object_poses=object_poses,
            region_positions=region_positions,
            joint_positions=joint_positions,
            eef_pos=observation.eef_pos,
            eef_quat=observation.eef_quat,
            gripper_qpos=observation.gripper_qpos,
            label=label,
            executed=executed,
        )
        return executed

    def act_batch(self, observations: list[Observation]) -> list[np.ndarray]:
        return [self.act(o) for o in observations]

    def finish(self, record: EpisodeRecord) -> None:
        """The runner's ``on_episode``: keep a successful demonstration, drop anything else."""
        recording = self._recordings.pop(record.episode_id, None)
        if recording is None or record.error:
            return  # an infrastructure failure: played again next time
        name = demonstration_name(record.suite, record.task_id, record.init_state)
        if not record.success:  # deterministic: it would fail again, so a resumed recording skips it
            with open(self.out / FAILED, "a", encoding="utf-8") as f:
                f.write(name + "\n")
            return
        arrays = {key: np.stack(values) for key, values in recording.frames.items()}
        # renamed into place whole: a stop mid-write leaves no truncated demonstration
        partial = self.out / f"{name}.npz.partial"
        with open(partial, "wb") as f:
            np.savez_compressed(
                f,
                instruction=np.array(recording.instruction),
                suite=np.array(record.suite),
                task_id=np.array(record.task_id),
                init_state=np.array(record.init_state),
                objects=np.array(recording.entities.objects),
                regions=np.array(recording.entities.regions),
                joints=np.array(recording.entities.joints),
                **arrays,
            )
        os.replace(partial, self.out / f"{name}.npz")
        self.written += 1
