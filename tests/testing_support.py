"""Helpers the core tests import by name (``from testing_support import ...``).

They live here rather than in ``conftest.py``: the model plugins' test folders have conftest modules of
their own, and ``from testing_support import`` would then reach whichever pytest imported last.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from conflictbench.core import ConflictCase, EpisodeRecord
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


TEST_EPISODE = dict(policy="p", suite="libero_goal", task_id=0, init_state=0, prompt="p0", instruction="x")
"""What an episode built by :func:`episode_record` is where the test does not say."""


def episode_record(**fields) -> EpisodeRecord:
    """An episode of the fields a test is about, the rest :data:`TEST_EPISODE`'s and the record's defaults."""
    return EpisodeRecord(**{**TEST_EPISODE, **fields})


def along_x(*x: float, action=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), target: str = "bowl") -> dict:
    """A record's arrays for a path through the states ``x`` on the x axis, one target (``target``) at the origin
    and ``action`` at every step: what the process measures read, as simple as a worked example needs."""
    steps = len(x) - 1
    return dict(
        eef_pos=np.stack([np.asarray(x, dtype=float), np.zeros(len(x)), np.zeros(len(x))], axis=1),
        target_pos=np.zeros((len(x), 1, 3)),
        target_names=(target,),
        actions=np.tile(np.asarray(action, dtype=float), (steps, 1)),
    )


def report_episode(
    policy, case, x_end, move, success, family=None, level=None, steps=1, init=0, error=None, error_kind=None
):
    """An episode of the report's tests: two recorded states on the x axis (target at the origin), one action of
    size ``move``, in libero_object's task 3."""
    key = dict(policy=policy, suite="libero_object", task_id=3, init_state=init, instruction="pick", case_id=case)
    outcome = dict(family=family, level=level, success=success, steps=steps, error=error, error_kind=error_kind)
    path = along_x(0.5, x_end, action=(move, 0, 0, 0, 0, 0, 1.0), target="alphabet_soup_1")
    return episode_record(**key, **outcome, **path, episode_id=f"{policy}-{case}-{init}", config_hash="cfg")


TRAMPOLINE = dict(
    step=1,
    role="destination",
    text="the purple trampoline",
    concept="trampoline",
    source="out_of_domain",
    replaces="plate_1",
)
"""A grounding witness's referent, out of any LIBERO scene: what a plugin's or a reviewer's own case may put in
place of libero_goal's plate ("put the bowl on the purple trampoline")."""


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
