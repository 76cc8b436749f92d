"""Helpers the core tests import by name (``from testing_support import ...``).

They live here rather than in ``conftest.py``: the model plugins' test folders have conftest modules of
their own, and ``from testing_support import`` would then reach whichever pytest imported last.
"""

from __future__ import annotations

import time
from pathlib import Path

from conflictbench.core import ConflictCase
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.tasks.libero.base_tasks import base_task


def reference_spec(suite: str, task_id: int, init_state: int = 0, prompt: str = "p0") -> EpisodeSpec:
    return EpisodeSpec(suite, task_id, init_state, prompt, base_task(suite, task_id).language)


def conflict_spec(case: ConflictCase, init_state: int = 0, prompt: str = "p0") -> EpisodeSpec:
    return EpisodeSpec(case.suite, case.task_id, init_state, prompt, base_task(case.suite, case.task_id).language, case)


DEMO_PLUGIN = Path(__file__).parent / "plugins" / "conflictbench-demo"


def pip_install_into(target: Path, source: Path, upgrade: bool = False) -> Path:
    """Install a plugin's source folder into ``target`` as a real distribution (its entry points found
    from ``PYTHONPATH`` or ``sys.path``), without touching the test environment."""
    import subprocess
    import sys

    command = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-compile"]
    subprocess.run([*command, *(["--upgrade"] if upgrade else []), "--target", str(target), str(source)], check=True)
    return target


def rejected(reasons: list[str], needle: str) -> list[str]:
    """``reasons`` (what a validation check says against a case), asserted to hold one that contains ``needle``."""
    assert any(needle in r for r in reasons), reasons
    return reasons


def wait_until(condition, seconds: float, every: float = 0.01) -> bool:
    """Whether ``condition()`` came to hold within ``seconds``, asked every ``every`` seconds: a test waits on
    the event it needs, not for a guessed time (too short on a slow machine, wasted on a fast one)."""
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(every)
    return True


def in_tasks(records, tasks: int) -> list:
    """``records`` played again in ``tasks`` base tasks (task ids 0..tasks-1, episode ids kept apart): the same
    outcomes in many clusters, so that intervals and paired comparisons have base tasks to rest on."""
    from dataclasses import replace

    return [replace(r, task_id=t, episode_id=f"{r.episode_id}-t{t}") for t in range(tasks) for r in records]
