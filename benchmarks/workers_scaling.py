"""Throughput of the worker pool: episodes per hour with workers=2 against workers=1.

Both runs play the same plan (no-op policy, several base tasks and initial states) into fresh
stores, side by side in one invocation. Goal on a 2-core machine: >= 1.6x. Pass --images to
measure a camera-based policy instead (software rendering already spreads over the cores, so
expect much less there).

    .venv/bin/python benchmarks/workers_scaling.py [--tasks 2] [--states 3] [--images]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import dataclass

import numpy as np

import conflictbench
from conflictbench import hookimpl


@dataclass
class StillConfig:
    images: bool = False


class Still:
    """The no-op action; optionally asks for camera images like a VLA would."""

    def __init__(self, cfg: StillConfig):
        self.needs_images = cfg.images

    def reset(self, instruction: str) -> None:
        pass

    def act(self, observation):
        return np.array([0, 0, 0, 0, 0, 0, -1.0])


class BenchPlugin:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("bench-still", load=Still, config=StillConfig)


def play(plan, workers: int, images: bool, backend: str = "local") -> float:
    """Seconds to play ``plan`` into a fresh store (the run's worker start included)."""
    from conflictbench.core.plugins import Plugins
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore

    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[BenchPlugin()])
    spec = plugins.policy("bench-still")
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        runner = Runner(
            plugins,
            spec,
            StillConfig(images),
            store=EpisodeStore(tmp),
            workers=workers,
            progress=False,
            backend=backend,
        )
        result = runner.run(plan)
        elapsed = time.perf_counter() - start
    assert result.played == len(plan) and result.errors == 0
    return elapsed


def reference_plan(suite: str, tasks: int, states: int) -> list:
    """The reference episodes of the first ``tasks`` base tasks of ``suite`` at its first ``states`` states."""
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.tasks.libero.base_tasks import base_task

    return [EpisodeSpec(suite, t, s, "p0", base_task(suite, t).language) for t in range(tasks) for s in range(states)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="libero_goal")
    parser.add_argument("--tasks", type=int, default=2)
    parser.add_argument("--states", type=int, default=3)
    parser.add_argument("--images", action="store_true")
    args = parser.parse_args()
    plan = reference_plan(args.suite, args.tasks, args.states)
    one = play(plan, 1, args.images)
    print(f"workers=1: {one:.1f} s  ({3600 * len(plan) / one:.0f} episodes/h)")
    two = play(plan, 2, args.images)
    print(f"workers=2: {two:.1f} s  ({3600 * len(plan) / two:.0f} episodes/h)")
    print(
        f"\n{len(plan)} episodes of {args.suite}, images={args.images}, {os.cpu_count()} cores, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(f"speed-up workers=2 / workers=1: {one / two:.2f}x   goal >= 1.6x")


if __name__ == "__main__":
    main()
