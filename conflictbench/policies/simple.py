"""Policies with no model: lower bounds and plumbing checks."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from conflictbench.core import Observation, rng_for

GRIPPER_OPEN = -1.0


class NoopPolicy:
    """Zero motion with the gripper open: the native warm-up action, forever."""

    needs_images = False

    def reset(self, instruction: str) -> None:
        pass

    def act(self, observation: Observation) -> np.ndarray:
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, GRIPPER_OPEN])

    def act_batch(self, observations: list[Observation]) -> list[np.ndarray]:
        return [self.act(o) for o in observations]


def noop(config: object) -> NoopPolicy:
    """``model=noop``'s loader: the policy has no settings."""
    return NoopPolicy()


@dataclass
class RandomConfig:
    seed: int = 0
    """Mixed into each decision's seed, which the episode's identity and step determine (``rng_for``)."""
    scale: float = 1.0
    """Arm actions are uniform in [-scale, scale]; the gripper is uniform in {-1, +1}."""


class RandomPolicy:
    """Seeded uniform random actions; the same episode always gets the same sequence, however it is scheduled."""

    needs_images = False

    def __init__(self, cfg: RandomConfig):
        self.cfg = cfg

    def reset(self, instruction: str) -> None:
        pass

    def act(self, observation: Observation) -> np.ndarray:
        rng = rng_for(observation, self.cfg.seed)
        arm = rng.uniform(-self.cfg.scale, self.cfg.scale, size=6)
        gripper = rng.choice([-1.0, 1.0])
        return np.concatenate([arm, [gripper]])

    def act_batch(self, observations: list[Observation]) -> list[np.ndarray]:
        return [self.act(o) for o in observations]
