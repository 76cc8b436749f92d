"""The "most favourable" mark, earned: a table's best value in a block is marked only where a paired
comparison over the pairs both models played tells it apart from the runner-up's (two-sided, 5 %;
:mod:`conflictbench.metrics.paired`) in the favourable direction. Models that share no pair cannot be told apart,
so neither is marked.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence

import pandas as pd

from conflictbench.metrics.intervals import Measure
from conflictbench.metrics.paired import EXPERIMENT_KEYS, differences, match

from .tables import Column, Marked, TableSpec, marks

ALPHA = 0.05


def _rows(frame: pd.DataFrame, row: pd.Series, keys: Sequence[str]) -> pd.DataFrame:
    chosen = frame["model"] == row["model"]
    for key in keys:
        value = row[key]
        chosen &= frame[key].isna() if value is None or value != value else frame[key] == value
    return frame[chosen]


def paired_marks(
    frame: pd.DataFrame, aggregates: pd.DataFrame, spec: TableSpec, measures: Mapping[str, Measure]
) -> Marked:
    """Which values of ``spec``'s table are marked (``frame``: the per-pair frame with ``model``; ``measures``:
    the report's measures by name, :func:`conflictbench.metrics.measures.report_measures`)."""
    metrics = [name for name in measures if name in frame.columns]

    @functools.cache
    def matched(a: int, b: int) -> pd.DataFrame:
        row_a, row_b = aggregates.loc[a], aggregates.loc[b]
        both = match(_rows(frame, row_a, spec.block), _rows(frame, row_b, spec.block), EXPERIMENT_KEYS, metrics)
        return both.frame

    def told_apart(best: int, runner: int, column: Column) -> bool:
        pairs = matched(best, runner)
        if pairs.empty:
            return False
        result = differences(pairs, (), [measures[column.measure]]).iloc[0]
        # on the pairs both played, the best must be better, not only different (their other pairs may differ)
        better = result[column.measure] > 0 if column.direction == "higher" else result[column.measure] < 0
        return bool(better and result[f"{column.measure}_p"] < ALPHA)

    flags, untold = marks(aggregates, spec, told_apart)
    return Marked(flags, tuple(untold))
