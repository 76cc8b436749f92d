"""Policies with no model: lower bounds and plumbing checks."""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from conflictbench.core import Observation

GRIPPER_OPEN = -1.0


class NoopPolicy:
    """Zero motion with the gripper open: the native warm-up action, forever."""

    needs_images = False

    def reset(self, instruction: str) -> None:
        pass

    def act(self, observation: Observation) -> np.ndarray:
        return np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, GRIPPER_OPEN])


@dataclass
class RandomConfig:
    seed: int = 0
    """Base seed; each episode draws from a generator seeded by (seed, instruction)."""
    scale: float = 1.0
    """Arm actions are uniform in [-scale, scale]; the gripper is uniform in {-1, +1}."""


class RandomPolicy:
    """Seeded uniform random actions; the same episode always gets the same sequence."""

    needs_images = False

    def __init__(self, cfg: RandomConfig):
        self.cfg = cfg
        self._rng = np.random.default_rng(cfg.seed)

    def reset(self, instruction: str) -> None:
        self._rng = np.random.default_rng([self.cfg.seed, zlib.crc32(instruction.encode())])

    def act(self, observation: Observation) -> np.ndarray:
        arm = self._rng.uniform(-self.cfg.scale, self.cfg.scale, size=6)
        gripper = self._rng.choice([-1.0, 1.0])
        return np.concatenate([arm, [gripper]])
