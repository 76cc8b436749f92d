"""``conflictbench compare``: is the difference between two models, two settings or two prompts real?

Each side is a model as the report labels it (``pi0``, ``random seed=1``), optionally at one prompt condition
(``subject@p1``), from one store or two. The pairs both sides played are matched on everything that makes
them the same experiment (:data:`~conflictbench.metrics.paired.EXPERIMENT_KEYS`; the prompt only where it is
not what is compared), and each measure's paired difference A - B is given with its 95 % interval clustered
by base task, overall, per family and per level, with a verdict: the overall row is tested at 5 %, the family
rows and the level rows each Holm-corrected among themselves.
"""

from __future__ import annotations

import difflib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import pandas as pd
from tabulate import tabulate

from conflictbench.core import PROMPT_CONDITIONS, MetricSpec, UserError
from conflictbench.core.words import counted
from conflictbench.metrics.aggregate import sort_groups
from conflictbench.metrics.intervals import Measure
from conflictbench.metrics.measures import DSR, FR, PCSR, RGSR, check_ranges, metric_measure, metric_ranges
from conflictbench.metrics.paired import EXPERIMENT_KEYS, differences, match, verdict

from .differences import difference_cell

ALPHA = 0.05
SCOPES = ("overall", "family", "level")


@dataclass(frozen=True)
class Side:
    """One side of a comparison: a model label, and a prompt condition or None (every one, matched)."""

    model: str
    prompt: str | None = None
    store: str = ""

    @property
    def text(self) -> str:
        return f"{self.model}{f'@{self.prompt}' if self.prompt else ''}"


def parse_side(text: str, store: str = "") -> Side:
    model, at, prompt = text.rpartition("@") if "@" in text else (text, "", "")
    if at and prompt not in PROMPT_CONDITIONS:
        raise UserError(f"{text!r}: the prompt condition after @ must be one of {', '.join(PROMPT_CONDITIONS)}")
    if not model.strip():
        raise UserError(f"{text!r}: give a model as the report names it, e.g. pi0 or subject@p1")
    return Side(model.strip(), prompt or None, store)


def check_side(side: Side, models: Sequence[str], prompts: Sequence[str]) -> None:
    """A one-line UserError where the store has no such model or prompt condition."""
    if side.model not in models:
        close = difflib.get_close_matches(side.model, list(models), n=1, cutoff=0.5)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise UserError(f"no model {side.model!r} in {side.store}: it has {', '.join(sorted(models))}{hint}")
    if side.prompt and side.prompt not in prompts:
        raise UserError(f"{side.text}: {side.store} holds no {side.prompt} pairs of {side.model}")


def compared_measures(metrics: Sequence[MetricSpec]) -> list[tuple[Measure, str, MetricSpec | None]]:
    """(measure, label, its spec or None for an outcome measure): table 1's columns over all pairs."""
    out = [(m, m.name, None) for m in (PCSR, RGSR, DSR, FR)]
    return out + [(metric_measure(m.name, m.bounds), m.label, m) for m in metrics]


@dataclass
class Comparison:
    a: Side
    b: Side
    keys: tuple[str, ...]
    table: pd.DataFrame
    """One row per (prompt, scope, group): pairs, clusters and the :func:`differences` columns, with
    ``X_p_adjusted`` (Holm among the family rows, among the level rows) and ``X_verdict``."""
    matched: int
    unmatched_a: Counter
    unmatched_b: Counter
    measures: list


def compare(
    a_frame: pd.DataFrame, b_frame: pd.DataFrame, a: Side, b: Side, metrics: Sequence[MetricSpec]
) -> Comparison:
    """``a_frame`` and ``b_frame``: per-pair frames (with ``model``) holding each side's pairs."""
    sides = []
    for frame, side in ((a_frame, a), (b_frame, b)):
        rows = frame[frame["model"] == side.model]
        sides.append(rows[rows["prompt"] == side.prompt] if side.prompt else rows)
    prompts_compared = bool(a.prompt and b.prompt and a.prompt != b.prompt)
    keys = tuple(k for k in EXPERIMENT_KEYS if not (prompts_compared and k == "prompt"))
    measures = compared_measures(metrics)
    names = [m.name for m in metrics]
    for frame in (a_frame, b_frame):
        check_ranges(frame, metric_ranges(metrics))
    matched = match(sides[0], sides[1], keys, names, carry=("prompt",) if not prompts_compared else ())
    pairs = matched.frame
    if prompts_compared:
        pairs = pairs.assign(prompt=f"{a.prompt} vs {b.prompt}")
    parts = []
    for prompt, block in pairs.groupby("prompt", sort=True) if len(pairs) else []:
        overall = differences(block, (), [m for m, _, _ in measures]).assign(scope="overall", group="all")
        family = differences(block, ("family",), [m for m, _, _ in measures], holm_within=True)
        level = differences(block, ("level",), [m for m, _, _ in measures], holm_within=True)
        family = sort_groups(family, ["family"]).rename(columns={"family": "group"}).assign(scope="family")
        level = sort_groups(level, ["level"]).rename(columns={"level": "group"}).assign(scope="level")
        parts.append(pd.concat([overall, family, level], ignore_index=True).assign(prompt=prompt))
    table = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()
    for measure, _, _ in measures if not table.empty else []:
        name = measure.name
        adjusted = table[f"{name}_p_holm"].where(table["scope"] != "overall", table[f"{name}_p"])
        table[f"{name}_p_adjusted"] = adjusted
        table[f"{name}_verdict"] = [verdict(d, p, ALPHA) for d, p in zip(table[name], adjusted)]
    return Comparison(a, b, keys, table, len(pairs), matched.unmatched_a, matched.unmatched_b, measures)


def _unmatched_line(side: Side, counts: Counter) -> str:
    if not counts:
        return f"every pair of {side.text} has its counterpart"
    reasons = ", ".join(f"{n} {reason}" for reason, n in counts.most_common())
    return f"{counted(sum(counts.values()), 'pair')} of {side.text} without a counterpart ({reasons} by the other side)"


KEY_WORDS = {"suite": "LIBERO suite", "task_id": "task", "case_id": "case", "conflict_suite": "suite version",
             "init_state": "initial state", "prompt": "prompt", "seed": "seed", "max_steps": "step budget"}  # fmt: skip


def render(result: Comparison) -> str:
    a, b = result.a, result.b
    where = a.store != b.store  # two stores: say which is which
    lines = [
        f"A = {a.text}{f' ({a.store})' if where else ''}, B = {b.text}{f' ({b.store})' if where else ''}",
        f"{counted(result.matched, 'matched pair')}, matched on {', '.join(KEY_WORDS.get(k, k) for k in result.keys)}",
        _unmatched_line(a, result.unmatched_a),
        _unmatched_line(b, result.unmatched_b),
    ]
    if result.table.empty:
        lines.append("nothing to compare: the two sides share no pair")
        return "\n".join(lines)
    for measure, label, spec in result.measures:
        percent, unit = (True, "") if spec is None else (spec.percent, spec.unit)
        name = measure.name
        header = ["prompt", "scope", "pairs", "tasks", "A", "B", "A - B [95 %]", "p", "verdict"]
        rows = []
        for _, r in result.table.iterrows():
            p = r[f"{name}_p_adjusted"]
            rows.append(
                [
                    str(r["prompt"]),
                    str(r["group"]),
                    str(int(r[f"{name}_n"])),
                    str(int(r[f"{name}_clusters"])),
                    _value(r[f"{name}_a"], percent, unit),
                    _value(r[f"{name}_b"], percent, unit),
                    difference_cell(r, name, percent, unit),
                    "n/a" if pd.isna(p) else f"{p:.3f}{' (Holm)' if r['scope'] != 'overall' else ''}",
                    r[f"{name}_verdict"],
                ]
            )
        where = "percentage points" if percent else (unit or "own units")
        lines += [
            "",
            f"== {label}: A - B ({where}) ==",
            tabulate(rows, header, tablefmt="simple", disable_numparse=True),
        ]
    lines += [
        "",
        "[95 % interval] of the paired difference, clustered by base task (tasks: how many the pairs come from); "
        "overall tested at 5 %, family rows and level rows each Holm-corrected among themselves (their p and "
        "verdict; the intervals are each row's own, so a family row's may leave out 0 without a difference called), "
        "each measure and prompt condition on its own; a metric counts where both sides define it, FR compares "
        "each side's qualified failures among its own successful references",
    ]
    return "\n".join(lines)


def _value(value, percent: bool, unit: str) -> str:
    if pd.isna(value):
        return "n/a"
    return f"{100 * value:.1f}" if percent else f"{value:.4g}{f' {unit}' if unit else ''}"


def csv_frame(result: Comparison) -> pd.DataFrame:
    """The table as CSV: prompt, scope, group, then per measure its sides, difference, interval, p-values,
    verdict, pairs and base tasks (rates and "%" metrics as fractions, as in the aggregates)."""
    if result.table.empty:
        return pd.DataFrame(columns=["prompt", "scope", "group"])
    columns = ["prompt", "scope", "group", "pairs", "clusters"]
    for measure, _, _ in result.measures:
        n = measure.name
        columns += [f"{n}_a", f"{n}_b", n, f"{n}_lo", f"{n}_hi", f"{n}_p", f"{n}_p_adjusted", f"{n}_verdict"]
        columns += [f"{n}_n", f"{n}_clusters"]
    return result.table[columns]
