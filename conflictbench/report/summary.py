"""The summary table printed at the end of a run and by ``conflictbench report``.

Rows: each model overall, then per conflict family. Columns: the outcome measures with their
counts, then the mean of every registered per-pair metric over the pairs where it is defined.
"""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence, TextIO

import pandas as pd

from conflictbench.core import EpisodeRecord, MetricSpec, Pair, UserError
from conflictbench.core.plugins import Plugins, unknown_choice
from conflictbench.metrics import delta_sr, failure_rate, make_pairs, pcsr, rgsr

GROUPINGS = {"overall": ("policy",), "family": ("policy", "family")}


@dataclass
class MetricValues:
    """Per-pair values of the selected metrics (None where undefined)."""

    names: list[str]
    values: list[dict[str, float | None]]


def select_metrics(plugins: Plugins, names: Sequence[str] | None) -> list[MetricSpec]:
    available = plugins.metrics()
    if names is None:
        return list(available.values())
    for name in names:
        if name not in available:
            raise UserError(unknown_choice("metric", name, available))
    return [available[n] for n in names]


def compute_metrics(pairs: Sequence[Pair], metrics: Sequence[MetricSpec]) -> MetricValues:
    values: list[dict[str, float | None]] = []
    failed: set[str] = set()
    for pair in pairs:
        row: dict[str, float | None] = {}
        for metric in metrics:
            try:
                value = metric.compute(pair)
                row[metric.name] = None if value is None or not math.isfinite(float(value)) else float(value)
            except Exception as exc:  # a broken third-party metric must not sink the report
                row[metric.name] = None
                if metric.name not in failed:
                    failed.add(metric.name)
                    warnings.warn(f"metric {metric.name!r} ({metric.plugin}) raised {type(exc).__name__}: {exc}")
        values.append(row)
    return MetricValues([m.name for m in metrics], values)


def summary_frame(pairs: Sequence[Pair], metrics: Sequence[MetricSpec], by: Sequence[str]) -> pd.DataFrame:
    computed = compute_metrics(pairs, metrics)
    groups: dict[tuple, list[int]] = {}
    for i, pair in enumerate(pairs):
        key = tuple(getattr(pair.conflict, field) for field in by)
        groups.setdefault(key, []).append(i)
    rows = []
    for key in sorted(groups, key=lambda k: tuple("" if v is None else str(v) for v in k)):
        members = [pairs[i] for i in groups[key]]
        p, r, f = pcsr(members), rgsr(members), failure_rate(members)
        row = {**dict(zip(by, key)), "pairs": len(members),
               "PCSR": p.value, "PCSR_k": p.k, "RGSR": r.value, "RGSR_k": r.k, "dSR": delta_sr(members),
               "FR": f.value, "FR_k": f.k, "FR_n": f.n}
        for name in computed.names:
            defined = [computed.values[i][name] for i in groups[key] if computed.values[i][name] is not None]
            row[name] = sum(defined) / len(defined) if defined else None
            row[f"{name}_n"] = len(defined)
        rows.append(row)
    return pd.DataFrame(rows)


def _fmt_rate(value: float | None, k: int, n: int) -> str:
    return "n/a (0/0)" if value is None or n == 0 else f"{100 * value:.1f} ({k}/{n})"


def render(frame: pd.DataFrame, by: Sequence[str], metric_names: Sequence[str]) -> str:
    if frame.empty:
        return "no pairs (a conflict episode and its reference) in this selection"
    header = [*by, "pairs", "PCSR", "RGSR", "dSR", "FR", *metric_names]
    lines = []
    for _, row in frame.iterrows():
        cells = [str(row[c]) if row[c] is not None else "-" for c in by]
        cells.append(str(row["pairs"]))
        cells.append(_fmt_rate(row["PCSR"], row["PCSR_k"], row["pairs"]))
        cells.append(_fmt_rate(row["RGSR"], row["RGSR_k"], row["pairs"]))
        cells.append("n/a" if row["dSR"] is None or pd.isna(row["dSR"]) else f"{100 * row['dSR']:.1f}")
        cells.append(_fmt_rate(row["FR"], row["FR_k"], row["FR_n"]))
        for name in metric_names:
            value, n = row[name], row[f"{name}_n"]
            cells.append(f"n/a (n=0)" if value is None or pd.isna(value) else f"{100 * value:.1f} (n={n})")
        lines.append(cells)
    widths = [max(len(h), *(len(c[i]) for c in lines)) for i, h in enumerate(header)]
    out = ["  ".join(h.ljust(w) for h, w in zip(header, widths)), "  ".join("-" * w for w in widths)]
    out += ["  ".join(c.ljust(w) for c, w in zip(cells, widths)) for cells in lines]
    return "\n".join(out)


def report_records(records: Iterable[EpisodeRecord], plugins: Plugins, *, out_dir: str | Path | None = None,
                   metrics: Sequence[str] | None = None, stream: TextIO | None = None) -> dict[str, pd.DataFrame]:
    """Print the summary tables for these episodes and, with ``out_dir``, write them as CSV."""
    stream = stream or sys.stdout
    selected = select_metrics(plugins, metrics)
    records = list(records)
    pairs, orphans = make_pairs(records)
    frames = {}
    names = [m.name for m in selected]
    for title, by in GROUPINGS.items():
        frame = summary_frame(pairs, selected, by)
        frames[title] = frame
        print(f"\n== {title} (rates in %, counts in brackets) ==", file=stream)
        print(render(frame, by, names), file=stream)
    references = sum(r.is_reference for r in records)
    errors = sum(r.error is not None for r in records)
    print(f"\n{len(records)} episodes ({references} reference, {len(records) - references} conflict), "
          f"{len(pairs)} pairs, {errors} with errors", file=stream)
    if orphans:
        print(f"{len(orphans)} conflict episode(s) have no stored reference yet and are left out", file=stream)
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for title, frame in frames.items():
            frame.to_csv(out / f"summary_{title}.csv", index=False)
        print(f"tables written to {out}/", file=stream)
    return frames
