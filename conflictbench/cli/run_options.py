"""The ``run`` group's options, checked: every value a person can type wrongly gets one clear line."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig

from conflictbench.core import LIBERO_SUITES, UserError
from conflictbench.sim import BACKENDS

INIT_STATES_PER_TASK = 50


@dataclass(frozen=True)
class RunOptions:
    """The ``run`` group, checked (every value a person can type wrongly gets a clear message)."""

    init_states: list[int]
    cases_per_cell: int | None
    sample_seed: int
    libero_suites: list[str]
    tasks: list[tuple[str, int]] | None
    cases: list[str] | None
    seed: int
    workers: int
    backend: str
    ray_address: str | None
    retry: bool
    stall_timeout_s: float | None
    max_steps: int | None
    out: Path
    metrics: list[str] | None
    progress: bool
    report: bool


def _int(value: Any, name: str, minimum: int = 0) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise UserError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return value


def checked_names(value: Any, name: str, allowed: tuple[str, ...]) -> list[str]:
    items = list(value) if isinstance(value, (list, ListConfig)) else [value]
    for item in items:
        if item not in allowed:
            raise UserError(f"unknown {name} {item!r}; valid choices: {', '.join(allowed)}")
    if not items:
        raise UserError(f"{name} must not be empty")
    return [str(i) for i in items]


def _seconds(value: Any, name: str) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value <= 0:
        raise UserError(f"{name} must be a number of seconds > 0, or null, got {value!r}")
    return float(value)


def _listed(value: Any, name: str) -> list[str] | None:
    if value is None:
        return None
    items = [str(v) for v in (value if isinstance(value, (list, ListConfig)) else [value])]
    if not items:
        raise UserError(f"{name} must name at least one, or be null")
    return items


def _base_tasks(value: Any) -> list[tuple[str, int]] | None:
    """``run.tasks``: ``libero_goal/3`` entries, checked (LIBERO's suites have tasks 0-9)."""
    import difflib

    named = _listed(value, "run.tasks")
    if named is None:
        return None
    tasks = []
    for entry in named:
        suite, _, task = entry.partition("/")
        if suite not in LIBERO_SUITES:
            close = difflib.get_close_matches(suite, LIBERO_SUITES, n=1)
            hint = f" (did you mean {close[0]}?)" if close else f"; suites: {', '.join(LIBERO_SUITES)}"
            raise UserError(f"run.tasks entries look like libero_goal/3; {entry!r} names no LIBERO suite{hint}")
        if not task.isdigit() or int(task) > 9:
            raise UserError(f"run.tasks entries look like libero_goal/3 (task ids 0-9), got {entry!r}")
        tasks.append((suite, int(task)))
    return sorted(set(tasks))


def run_options(run: DictConfig) -> RunOptions:
    states = run.init_states
    if isinstance(states, (list, ListConfig)):
        init_states = sorted({_int(s, "run.init_states entries") for s in states})
        if not init_states:
            raise UserError("run.init_states must name at least one initial state")
    else:
        count = _int(states, "run.init_states", minimum=1)
        if count > INIT_STATES_PER_TASK:
            raise UserError(
                f"run.init_states={count}, but LIBERO has {INIT_STATES_PER_TASK} fixed initial states per task"
            )
        init_states = list(range(count))
    if init_states[-1] >= INIT_STATES_PER_TASK:
        raise UserError(f"run.init_states names state {init_states[-1]}; LIBERO's are 0..{INIT_STATES_PER_TASK - 1}")
    per_cell = run.cases_per_cell
    cases_per_cell = None if per_cell == "all" else _int(per_cell, "run.cases_per_cell (or 'all')")
    metrics = (
        None
        if run.metrics is None
        else [str(m) for m in (run.metrics if isinstance(run.metrics, (list, ListConfig)) else [run.metrics])]
    )
    return RunOptions(
        init_states=init_states,
        cases_per_cell=cases_per_cell,
        sample_seed=_int(run.sample_seed, "run.sample_seed"),
        libero_suites=checked_names(run.libero_suites, "LIBERO suite", LIBERO_SUITES),
        tasks=_base_tasks(run.get("tasks")),
        cases=_listed(run.get("cases"), "run.cases"),
        seed=_int(run.seed, "run.seed"),
        workers=_int(run.workers, "run.workers", minimum=1),
        backend=checked_names(run.backend, "run.backend", BACKENDS)[0],
        ray_address=None if run.ray_address is None else str(run.ray_address),
        retry=bool(run.get("retry", False)),
        stall_timeout_s=_seconds(run.get("stall_timeout_s"), "run.stall_timeout_s"),
        max_steps=None if run.get("max_steps") is None else _int(run.max_steps, "run.max_steps (or null)", minimum=1),
        out=Path(str(run.out)),
        metrics=metrics,
        progress=bool(run.progress),
        report=bool(run.report),
    )
