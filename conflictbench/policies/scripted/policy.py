"""The scripted expert: achieves the base task's BDDL goal from privileged state, whatever it is told."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from conflictbench.core import Observation, PerEpisode

from .control import OPEN, servo
from .primitives import Context, Skill
from .scene import Scene
from .tasks import achieve

ATTEMPTS = 3
"""Tries per goal predicate before the expert gives up on it."""


@dataclass
class ScriptedConfig:
    max_steps: dict[str, int] = field(
        default_factory=lambda: {"libero_spatial": 300, "libero_object": 300, "libero_goal": 600, "libero_10": 1000}
    )
    """Episode budget per LIBERO suite (longer than learned policies get: the expert moves slowly)."""


@dataclass
class _Episode:
    ctx: Context | None = None
    plan: Skill | None = None


class ScriptedPolicy:
    """Privileged, deterministic, camera-free expert for the 40 LIBERO base tasks.

    It reads the goal predicates from ``observation.privileged.goal`` and never reads the
    instruction, so on a conflict episode it keeps executing the original task: the reference
    point for maximal Failed Persistence. One instance serves every worker: its per-episode
    state (the plan being executed) is kept per stream.
    """

    needs_images = False
    needs_privileged = True

    def __init__(self, cfg: ScriptedConfig | None = None):
        self.cfg = cfg or ScriptedConfig()
        self.max_steps = dict(self.cfg.max_steps)
        self._episodes: PerEpisode[_Episode] = PerEpisode(_Episode)

    def reset(self, instruction: str) -> None:
        """Nothing to do: the instruction is deliberately ignored, and a new episode starts its own state."""

    def act(self, observation: Observation) -> np.ndarray:
        scene = Scene(observation)
        episode = self._episodes(observation)
        if episode.ctx is None:
            table = min(scene.box(n)[0, 2] for n in scene.geo.objects if scene.has(n))
            episode.ctx = Context(scene=scene, theta=scene.finger_theta, table=float(table))
            episode.plan = _run(episode.ctx, tuple(observation.privileged.goal))
        episode.ctx.scene = scene
        try:
            return next(episode.plan)
        except StopIteration:
            episode.plan = _idle(episode.ctx)
            return next(episode.plan)

    def act_batch(self, observations: list[Observation]) -> list[np.ndarray]:
        """Concurrent episodes, one after another (each stream's plan is its own)."""
        return [self.act(o) for o in observations]


def _idle(ctx: Context) -> Skill:
    pos = ctx.scene.eef.copy()
    while True:
        yield servo(ctx.scene, pos, ctx.orientation, ctx.grip)


def order(goal: tuple[tuple[str, ...], ...]) -> list[int]:
    """Work order: turn knobs and open things first, then place objects, then close things."""
    rank = {"turnon": 0, "turnoff": 0, "open": 1, "on": 2, "in": 2, "close": 3}
    return sorted(range(len(goal)), key=lambda i: (rank.get(goal[i][0], 2), i))


def _run(ctx: Context, goal: tuple[tuple[str, ...], ...]) -> Skill:
    yield from _settle(ctx)
    tries = [0] * len(goal)
    while True:
        pending = [i for i in order(goal) if not ctx.scene.holds(i) and tries[i] < ATTEMPTS]
        if not pending:
            return True
        i = pending[0]
        tries[i] += 1
        yield from achieve(ctx, goal, i)


def _settle(ctx: Context, steps: int = 5) -> Skill:
    pos = ctx.scene.eef.copy()
    for _ in range(steps):
        yield servo(ctx.scene, pos, ctx.orientation, OPEN)
    return True
