"""Paired differences as text: the report's P0 - P1 table and ``conflictbench compare``'s tables.

A difference is shown with its 95 % interval, clustered by base task like every interval of the report
(:mod:`conflictbench.metrics.intervals`): "+12.5 [-3.1, +28.0]" in percentage points for rates and "%"
metrics, in the metric's unit otherwise.
"""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd
from tabulate import tabulate

from conflictbench.core import MetricSpec

#: The outcome rates compared between P0 and P1 (this report's own columns, fractions shown in %).
OUTCOME_DIFFERENCES = ("PCSR", "RGSR")


def _defined(value) -> bool:
    return value is not None and not pd.isna(value)


def signed(value: float, percent: bool = True, unit: str = "") -> str:
    return f"{100 * value:+.1f}" if percent else f"{value:+.4g}{f' {unit}' if unit else ''}"


def difference_cell(row: pd.Series, name: str, percent: bool = True, unit: str = "", star: bool = False) -> str:
    """ "+12.5 [-3.1, +28.0]" (``star``: a "*" where the interval leaves out 0), "n/a (n=0)" where undefined."""
    value = row.get(name)
    if not _defined(value):
        return "n/a (n=0)"
    low, high = row.get(f"{name}_lo"), row.get(f"{name}_hi")
    interval = f" [{signed(low, percent)}, {signed(high, percent)}]" if _defined(low) and _defined(high) else " [n/a]"
    called = star and _defined(row.get(f"{name}_p")) and row[f"{name}_p"] < 0.05
    return f"{signed(value, percent, unit)}{interval}{'*' if called else ''}"


def prompt_measures(metrics: Sequence[MetricSpec]) -> list[tuple[str, str, bool, str]]:
    """(name, label, percent, unit) of each measure the P0 - P1 table shows."""
    return [(m, m, True, "") for m in OUTCOME_DIFFERENCES] + [(m.name, m.label, m.percent, m.unit) for m in metrics]


def render_prompt_differences(summary: pd.DataFrame, metrics: Sequence[MetricSpec]) -> str:
    """Paired P0 - P1 differences per model (percentage points where the unit is "%"), 95 % intervals."""
    measures = prompt_measures(metrics)
    header = ["model", "pairs", "tasks", *(label for _, label, _, _ in measures)]
    rows = [
        [str(r["model"]), str(int(r["pairs"])), str(int(r["clusters"]))]
        + [difference_cell(r, name, percent, unit, star=True) for name, _, percent, unit in measures]
        for _, r in summary.iterrows()
    ]
    return "\n".join(
        [
            "== Paired P0 - P1 differences (same case, initial state, seed and settings; percentage points for rates "
            "and % measures, other units as registered) ==",
            tabulate(rows, header, tablefmt="simple", disable_numparse=True),
            "[95 % interval] over base tasks (tasks: how many the pairs come from); * P0 and P1 differ (paired "
            "test, 5 %, each measure on its own); a metric counts where both prompts define it",
        ]
    )
