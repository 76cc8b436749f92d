"""Shared fixtures. Simulation tests play real LIBERO episodes through the real runner."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import pytest

import conflictbench
from conflictbench.core import ConflictCase
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.runner import Runner, RunResult
from conflictbench.store import EpisodeStore
from conflictbench.tasks.libero_tasks import base_task


@pytest.fixture(scope="session")
def plugins():
    return conflictbench.plugins()


def reference_spec(suite: str, task_id: int, init_state: int = 0, prompt: str = "p0") -> EpisodeSpec:
    return EpisodeSpec(suite, task_id, init_state, prompt, base_task(suite, task_id).language)


def conflict_spec(case: ConflictCase, init_state: int = 0, prompt: str = "p0") -> EpisodeSpec:
    return EpisodeSpec(case.suite, case.task_id, init_state, prompt, base_task(case.suite, case.task_id).language, case)


@pytest.fixture
def play(tmp_path: Path, plugins):
    """play(policy_name, specs, settings=None, workers=1, store_dir=None) -> (RunResult, EpisodeStore)."""

    def _play(policy: str, specs: Sequence[EpisodeSpec], settings: dict | None = None, workers: int = 1,
              store_dir: Path | None = None, plugin_set=None) -> tuple[RunResult, EpisodeStore]:
        pl = plugin_set or plugins
        spec = pl.policy(policy)
        store = EpisodeStore(store_dir or tmp_path / "store")
        runner = Runner(pl, spec, spec.make_config(settings or {}), store=store, workers=workers, progress=False)
        return runner.run(list(specs)), store

    return _play
