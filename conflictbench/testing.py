"""Helpers for a model plugin's own tests: real runs of the ``conflictbench`` command on a small selection.

The selection (:data:`ONE_CASE`) is one physical-feasibility L1 case of libero_spatial and its reference
episode, at the first initial state: two real LIBERO episodes, about half a minute each on a CPU. ::

    from conflictbench.testing import episode_counts, planned_conflict_instruction, run_cli

    out = run_cli(tmp_path, "model=mymodel", "model.server=...", "model.max_steps=16")
    assert out.returncode == 0 and episode_counts(out.stderr) == (2, 0, 0)

Needs the simulator (the ``sim`` extra); mark such tests ``@pytest.mark.sim``.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

#: One physical L1 case of libero_spatial and its reference, first initial state, no progress bar or report.
ONE_CASE = ("suite=physical", "level=L1", "run.cases_per_cell=1", "run.libero_suites=[libero_spatial]")


def run_cli(
    tmp_path: Path,
    *overrides: str,
    out: str = "results",
    env: Mapping[str, str] | None = None,
    timeout: float = 900,
) -> subprocess.CompletedProcess:
    """``conflictbench`` on :data:`ONE_CASE` with ``overrides``, its store in ``tmp_path / out``."""
    args = [*ONE_CASE, "run.progress=false", "run.report=false", f"run.out={tmp_path / out}", *overrides]
    return subprocess.run(
        [sys.executable, "-m", "conflictbench.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        cwd=tmp_path,
        env=None if env is None else dict(env),
    )


def episode_counts(stderr: str) -> tuple[int, int, int]:
    """(played, already stored, with errors) from a run's closing line."""
    found = re.search(r"(\d+) played, (\d+) already stored, \d+ played by another job, (\d+) with errors", stderr)
    if found is None:
        raise AssertionError(f"no closing line in the run's output:\n{stderr[-3000:]}")
    return int(found[1]), int(found[2]), int(found[3])


def planned_conflict_instruction() -> str:
    """The conflict instruction :data:`ONE_CASE` plays (a server can be told to fail on exactly that episode)."""
    from .sim.plan import build_plan
    from .tasks.libero.base_tasks import all_base_tasks
    from .tasks.suite.file import load_suite

    tasks = {t.key: t.language for t in all_base_tasks(("libero_spatial",))}
    plan = build_plan(
        load_suite(None).cases, base_instructions=tasks, families=["physical"], levels=["L1"], prompts=["p0"],
        init_states=[0], cases_per_cell=1, sample_seed=0, libero_suites=["libero_spatial"],
    )  # fmt: skip
    [conflict] = [spec for spec in plan if spec.case is not None]
    return conflict.case.instruction
