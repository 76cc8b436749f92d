"""Simulated stores with a known truth, for the coverage and comparison tests of the report's intervals.

The generator is fixed here, not tuned to the method: crossed random effects on a probit (latent normal) scale,
with the variance components measured on a real store of the learned subject
(``conflictbench/metrics/correlations.json``, README "Uncertainty"), the suite's real layout of cases, and
references shared as the runner shares them (one per base task and initial state, reused by every case).

- A reference episode (task t, initial state s) succeeds where mu+ + A_t + R_ts > 0,
- a conflict episode (t, case c, s) completes the original goal where mu- + T_t + C_tc + S_ts + E_tcs > 0,
- a pair's TS is Phi(mu_x + T'_t + C'_tc + S'_ts + E'_tcs),
each latent of variance 1, so the true rates are Phi(mu): PCSR = Phi(mu+), RGSR = Phi(mu-), TS's true mean
Phi(mu_x / sqrt(2)), and FR = (PCSR - P(both succeed)) / PCSR from the bivariate normal of the two latents, whose
correlation is cov(A, T) + cov(R, S) (those covariances: the measured reference-conflict correlations, within
what the components allow). Two models share a part of every random effect's variance: the correlation measured
between two settings of the learned subject on the same episodes (``between_models`` in the measurements), for
their reference outcomes, their conflict outcomes and their TS.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from importlib import resources

import numpy as np
import pandas as pd
from scipy import special, stats

from conflictbench.metrics.measures import DSR, FR, PCSR, RGSR, metric_measure

MEASURES = (PCSR, RGSR, DSR, FR, metric_measure("ts", (0.0, 1.0)))


@functools.cache
def measured() -> dict:
    with (resources.files("conflictbench.metrics") / "correlations.json").open(encoding="utf-8") as f:
        return json.load(f)


@dataclass(frozen=True)
class Components:
    """Latent variance components (each latent's total variance is 1)."""

    task: float
    case: float
    state: float
    reference_task: float
    cross_task: float
    cross_state: float
    ts_task: float
    ts_case: float
    ts_state: float
    shared_reference: float
    shared_conflict: float
    shared_ts: float

    @classmethod
    def from_measurements(cls) -> Components:
        m = measured()
        conflict, reference = m["latent"]["conflict_success"], m["latent"]["reference_success"]
        task = max(0.0, conflict["task"])
        case = max(0.0, conflict["case"] - task)
        state = max(0.0, conflict["state"] - task)
        total = task + case + state
        if total > 0.98:  # room for a residual: every episode is its own draw too
            task, case, state = (0.98 * x / total for x in (task, case, state))
        reference_task = min(0.98, max(0.0, reference["task"]))
        cross = m["latent"].get("cross", {})
        limit_task = np.sqrt(reference_task * task)
        limit_state = np.sqrt((1 - reference_task) * state)
        ts = m["ts"]
        ts_task = max(0.0, ts["task"])
        ts_case, ts_state = max(0.0, ts["case"] - ts_task), max(0.0, ts["state"] - ts_task)
        ts_total = ts_task + ts_case + ts_state
        if ts_total > 0.98:
            ts_task, ts_case, ts_state = (0.98 * x / ts_total for x in (ts_task, ts_case, ts_state))
        between = m["between_models"]
        return cls(
            task, case, state, reference_task,
            float(np.clip(cross.get("task", 0.0), -limit_task, limit_task)),
            float(np.clip(cross.get("state", 0.0), -limit_state, limit_state)),
            ts_task, ts_case, ts_state,
            *(float(np.clip(between[k], 0, 1)) for k in ("reference_success_latent", "conflict_success_latent", "ts")),
        )  # fmt: skip


@dataclass(frozen=True)
class Layout:
    """The cases of a slice (suite, task, case id, family, level), played from each of ``states``."""

    cases: pd.DataFrame
    states: int

    @property
    def pairs(self) -> int:
        return len(self.cases) * self.states


def suite_layout(cases_per_cell: int | None, states: int, sample_seed: int = 0) -> Layout:
    """The shipped suite's cases a run with these options plays (``None``: every case, ``run=paper``)."""
    from conflictbench.core import FAMILIES, LEVELS
    from conflictbench.sim.plan import build_plan
    from conflictbench.tasks.suite.file import load_suite

    suite = load_suite(None)
    tasks = {(c.suite, c.task_id): c.base_instruction for c in suite.cases}
    plan = build_plan(
        suite.cases, base_instructions=tasks, families=FAMILIES, levels=LEVELS, prompts=("p0",),
        init_states=list(range(states)), cases_per_cell=cases_per_cell, sample_seed=sample_seed,
    )  # fmt: skip
    chosen = {e.case.case_id: e.case for e in plan if e.case is not None}
    rows = [(c.suite, c.task_id, c.case_id, c.family, c.level) for c in chosen.values()]
    frame = pd.DataFrame(rows, columns=["suite", "task_id", "case_id", "family", "level"])
    return Layout(frame.sort_values(["suite", "task_id", "case_id"]).reset_index(drop=True), states)


@dataclass(frozen=True)
class Truth:
    PCSR: float
    RGSR: float
    dSR: float
    FR: float
    ts: float


def truth(pcsr: float, rgsr: float, ts: float, comp: Components) -> Truth:
    cross = comp.cross_task + comp.cross_state
    mu_ref, mu_con = stats.norm.ppf(pcsr), stats.norm.ppf(rgsr)
    both = stats.multivariate_normal.cdf([mu_ref, mu_con], mean=[0, 0], cov=[[1, cross], [cross, 1]])
    return Truth(pcsr, rgsr, pcsr - rgsr, (pcsr - both) / pcsr, ts)


def _effect(rng, shape, variance, shared=None, share=0.0):
    """Normal effects of ``variance``; with ``shared`` (the models' common draw) ``share`` of it in common."""
    if shared is None:
        return rng.standard_normal(shape) * np.sqrt(variance)
    own = rng.standard_normal(shape)
    return np.sqrt(variance) * (np.sqrt(share) * shared + np.sqrt(1 - share) * own)


def simulate(
    layout: Layout,
    stores: int,
    rng: np.random.Generator,
    comp: Components,
    rates: tuple[float, float, float],
    models: int = 1,
    second_rates: tuple[float, float, float] | None = None,
) -> pd.DataFrame:
    """``stores`` simulated stores of ``layout`` (column ``store``); with ``models=2``, each side's outcomes
    suffixed ``_a`` and ``_b`` (side B at ``second_rates``), else unsuffixed."""
    cases = layout.cases
    task_keys = pd.factorize(cases["suite"] + "/" + cases["task_id"].astype(str))[0]
    n_tasks, n_cases, n_states = task_keys.max() + 1, len(cases), layout.states
    case_task = np.repeat(task_keys, n_states)  # pairs: case-major, then state
    case_index = np.repeat(np.arange(n_cases), n_states)
    state_index = np.tile(np.arange(n_states), n_cases)
    n_pairs = n_cases * n_states
    shape_t, shape_c, shape_s, shape_p = (
        (stores, n_tasks),
        (stores, n_cases),
        (stores, n_tasks, n_states),
        (stores, n_pairs),
    )
    common = {
        name: rng.standard_normal(shape)
        for name, shape in (("A", shape_t), ("T", shape_t), ("C", shape_c), ("R", shape_s), ("S", shape_s),
                            ("E", shape_p), ("T'", shape_t), ("C'", shape_c), ("S'", shape_s), ("E'", shape_p))
    } if models == 2 else None  # fmt: skip
    columns: dict[str, np.ndarray] = {}
    for side, side_rates in enumerate((rates, second_rates or rates)[:models]):

        def shared(name):  # (the common draw of this effect, the share of its variance in common)
            share = {
                "A": comp.shared_reference,
                "R": comp.shared_reference,
                "T'": comp.shared_ts,
                "C'": comp.shared_ts,
                "S'": comp.shared_ts,
                "E'": comp.shared_ts,
            }.get(name, comp.shared_conflict)
            return (common[name], share) if common else (None, 0.0)

        pcsr, rgsr, ts_mean = side_rates
        # the reference's task effect A and the conflict's T share cross_task; R (per task and state) and S
        # share cross_state: built as correlated normals
        a = _effect(rng, shape_t, 1.0, *shared("A"))
        t_own = _effect(rng, shape_t, 1.0, *shared("T"))
        rho_t = comp.cross_task / np.sqrt(comp.reference_task * comp.task) if comp.reference_task * comp.task else 0
        t = np.sqrt(comp.task) * (rho_t * a + np.sqrt(max(0.0, 1 - rho_t**2)) * t_own)
        a = np.sqrt(comp.reference_task) * a
        r = _effect(rng, shape_s, 1.0, *shared("R"))
        s_own = _effect(rng, shape_s, 1.0, *shared("S"))
        ref_rest = 1 - comp.reference_task
        rho_s = comp.cross_state / np.sqrt(ref_rest * comp.state) if ref_rest * comp.state else 0
        s = np.sqrt(comp.state) * (rho_s * r + np.sqrt(max(0.0, 1 - rho_s**2)) * s_own)
        r = np.sqrt(ref_rest) * r
        c = _effect(rng, shape_c, comp.case, *shared("C"))
        e = _effect(rng, shape_p, 1 - comp.task - comp.case - comp.state, *shared("E"))
        reference = stats.norm.ppf(pcsr) + a[:, case_task] + r[:, case_task, state_index] > 0
        conflict = stats.norm.ppf(rgsr) + t[:, case_task] + c[:, case_index] + s[:, case_task, state_index] + e > 0
        mu_x = stats.norm.ppf(ts_mean) * np.sqrt(2)
        latent_x = (
            mu_x
            + _effect(rng, shape_t, comp.ts_task, *shared("T'"))[:, case_task]
            + _effect(rng, shape_c, comp.ts_case, *shared("C'"))[:, case_index]
            + _effect(rng, shape_s, comp.ts_state, *shared("S'"))[:, case_task, state_index]
            + _effect(rng, shape_p, 1 - comp.ts_task - comp.ts_case - comp.ts_state, *shared("E'"))
        )
        suffix = ("_a", "_b")[side] if models == 2 else ""
        columns[f"reference_success{suffix}"] = reference.ravel()
        columns[f"conflict_success{suffix}"] = conflict.ravel()
        columns[f"ts{suffix}"] = special.ndtr(latent_x).ravel()
    frame = pd.DataFrame(
        {
            "store": np.repeat(np.arange(stores), n_pairs),
            "suite": pd.Categorical(np.tile(cases["suite"].to_numpy()[case_index], stores)),
            "task_id": np.tile(cases["task_id"].to_numpy()[case_index], stores),
            "case_id": pd.Categorical(np.tile(cases["case_id"].to_numpy()[case_index], stores)),
            "init_state": np.tile(state_index, stores),
            "family": pd.Categorical(np.tile(cases["family"].to_numpy()[case_index], stores)),
            "level": pd.Categorical(np.tile(cases["level"].to_numpy()[case_index], stores)),
            **columns,
        }
    )
    return frame
