"""The paper's three tables, built from aggregates, rendered for the terminal, Markdown, LaTeX and CSV.

Built-in measures are percentages with one decimal (plugin metrics as they come), each with its
counts: "78.7 (315/400)" for a rate, "76.5 (n=310)" for a mean over the pairs where the measure is
defined; an empty subset reads "n/a (0/0)" or "n/a (n=0)".

In each column the most favourable value is marked (terminal "*", Markdown bold, LaTeX \\textbf)
among the rows of the same prompt condition (and family in the family table), when at least two
rows have a value and they are not all equal. Directions (:data:`DIRECTIONS`): a more capable
policy has a higher PCSR; a better conflict response has a lower RGSR, TAR, Early20 TS and TS (it
did not keep pursuing the invalid goal along the reference path) and a higher dSR, AMS and FR (its
success dropped under the conflict, it held back its motion, it left the original goal undone
when it was able to do it). Plugin metrics are unmarked unless ``directions`` names theirs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import pandas as pd

from conflictbench.metrics import BUILTIN_METRICS

LABELS = {"tar": "TAR", "ts": "TS", "early20_ts": "Early20_TS", "ams": "AMS"}
DIRECTIONS = {"PCSR": "higher", "RGSR": "lower", "dSR": "higher", "FR": "higher",
              "tar": "lower", "ts": "lower", "early20_ts": "lower", "ams": "higher"}
KEY_LABELS = {"model": "model", "prompt": "prompt", "family": "family"}
BLOCK_WORDS = {"prompt": "prompt condition", "family": "family"}


@dataclass(frozen=True)
class Column:
    label: str
    kind: str  # "rate" (value with k/n), "diff" (dSR, with n), "mean" (with n)
    value: str  # aggregate column holding the fraction
    k: str | None = None
    n: str = "pairs"
    direction: str | None = None
    percent: bool = True  # built-in measures are fractions, shown in %; a plugin metric as it comes


@dataclass(frozen=True)
class TableSpec:
    name: str
    title: str
    grouping: str  # key of conflictbench.metrics.GROUPINGS
    keys: tuple[str, ...]
    block: tuple[str, ...]  # rows compared with each other when marking the most favourable value
    columns: tuple[Column, ...]


def _metric_column(name: str, qualified_failures: bool, directions: Mapping[str, str]) -> Column:
    suffix = "_qf" if qualified_failures else ""
    return Column(LABELS.get(name, name), "mean", f"{name}{suffix}", n=f"{name}{suffix}_n",
                  direction=directions.get(name), percent=name in BUILTIN_METRICS)


def paper_tables(metrics: Sequence[str], directions: Mapping[str, str] | None = None) -> list[TableSpec]:
    """Table 1 (overall), 2 (by family) and 3 (FR and means over qualified failures), as in the paper,
    with every other selected metric appended after the built-ins."""
    d = {**DIRECTIONS, **(directions or {})}
    outcome = (Column("PCSR", "rate", "PCSR", k="PCSR_k", direction=d["PCSR"]),
               Column("RGSR", "rate", "RGSR", k="RGSR_k", direction=d["RGSR"]),
               Column("dSR", "diff", "dSR", direction=d["dSR"]))
    extra = [m for m in metrics if m not in BUILTIN_METRICS]

    def chosen(names: Sequence[str]) -> list[str]:
        return [m for m in names if m in metrics] + extra

    overall = outcome + tuple(_metric_column(m, False, d) for m in chosen(("tar", "early20_ts", "ts", "ams")))
    family = outcome + tuple(_metric_column(m, False, d) for m in chosen(("tar", "ts", "ams")))
    failures = (Column("FR", "rate", "FR", k="FR_k", n="FR_n", direction=d["FR"]),) + tuple(
        _metric_column(m, True, d) for m in chosen(("tar", "early20_ts", "ts", "ams")))
    return [
        TableSpec("table1_overall", "Table 1: overall outcome and process measures", "model",
                  ("model", "prompt"), ("prompt",), overall),
        TableSpec("table2_by_family", "Table 2: by conflict family", "family",
                  ("model", "prompt", "family"), ("prompt", "family"), family),
        TableSpec("table3_qualified_failures", "Table 3: failure rate among qualified pairs (FR) and process "
                  "measures over the qualified failures D_QF", "model", ("model", "prompt"), ("prompt",), failures),
    ]


def _defined(value) -> bool:
    return value is not None and not (isinstance(value, float) and math.isnan(value))


def _count(row: pd.Series, column: str | None) -> int:
    return int(row[column]) if column and _defined(row[column]) else 0


def marks(aggregates: pd.DataFrame, spec: TableSpec) -> pd.DataFrame:
    """Boolean frame (same index, one column per label): is this the most favourable value of its block?"""
    out = pd.DataFrame(False, index=aggregates.index, columns=[c.label for c in spec.columns])
    if aggregates.empty:
        return out
    blocks = ([sub.index for _, sub in aggregates.groupby(list(spec.block), dropna=False, sort=False)]
              if spec.block else [aggregates.index])
    for column in spec.columns:
        if column.direction not in ("higher", "lower"):
            continue
        for index in blocks:
            values = aggregates.loc[index, column.value].astype(float)
            counts = aggregates.loc[index, column.n].astype(float)
            values = values[values.notna() & (counts > 0)]
            if len(values) < 2 or values.nunique() == 1:  # nothing to tell apart
                continue
            best = values.max() if column.direction == "higher" else values.min()
            out.loc[values.index[values == best], column.label] = True
    return out


def cell(row: pd.Series, column: Column) -> str:
    value = row[column.value]
    n = _count(row, column.n)
    if column.kind == "rate":
        k = _count(row, column.k)
        return f"{100 * value:.1f} ({k}/{n})" if _defined(value) and n else f"n/a ({k}/{n})"
    if not (_defined(value) and n):
        return f"n/a (n={n})"
    return f"{100 * value:.1f} (n={n})" if column.percent else f"{value:.4g} (n={n})"


def _key_text(value) -> str:
    return str(value) if _defined(value) else "-"


def text_rows(aggregates: pd.DataFrame, spec: TableSpec) -> tuple[list[str], list[list[str]], pd.DataFrame]:
    header = [KEY_LABELS.get(k, k) for k in spec.keys] + [c.label for c in spec.columns]
    best = marks(aggregates, spec)
    rows = [[_key_text(row[k]) for k in spec.keys] + [cell(row, c) for c in spec.columns]
            for _, row in aggregates.iterrows()]
    return header, rows, best


def legend(spec: TableSpec) -> str:
    higher = [c.label for c in spec.columns if c.direction == "higher"]
    lower = [c.label for c in spec.columns if c.direction == "lower"]
    within = " and ".join(BLOCK_WORDS.get(b, b) for b in spec.block) or "the table"
    parts = ([f"higher {', '.join(higher)}"] if higher else []) + ([f"lower {', '.join(lower)}"] if lower else [])
    return (f"rates and means in %, counts in brackets; * most favourable per column within each {within} "
            f"({'; '.join(parts)})")


def render_text(aggregates: pd.DataFrame, spec: TableSpec) -> str:
    if aggregates.empty:
        return f"== {spec.title} ==\nn/a: no pairs (0 pairs with both a conflict episode and its reference)"
    header, rows, best = text_rows(aggregates, spec)
    nkeys = len(spec.keys)
    for r, flags in zip(rows, best.itertuples(index=False)):
        for j, flag in enumerate(flags):
            r[nkeys + j] = r[nkeys + j] + ("*" if flag else " ")
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    lines = [f"== {spec.title} ==", "  ".join(h.ljust(w) for h, w in zip(header, widths)),
             "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    lines.append(legend(spec))
    return "\n".join(lines)


def render_markdown(aggregates: pd.DataFrame, spec: TableSpec) -> str:
    header, rows, best = text_rows(aggregates, spec)
    nkeys = len(spec.keys)
    lines = [f"### {spec.title}", "", "| " + " | ".join(header) + " |",
             "|" + "|".join(["---"] * nkeys + ["---:"] * len(spec.columns)) + "|"]
    for r, flags in zip(rows, best.itertuples(index=False)):
        cells = r[:nkeys] + [f"**{c}**" if flag else c for c, flag in zip(r[nkeys:], flags)]
        lines.append("| " + " | ".join(cells) + " |")
    if not rows:
        lines.append("| " + " | ".join(["n/a (0 pairs)"] + [""] * (len(header) - 1)) + " |")
    lines += ["", legend(spec).replace("* most", "bold: most"), ""]
    return "\n".join(lines)


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
        "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def tex_escape(text: str) -> str:
    return "".join(_TEX.get(ch, ch) for ch in text)


def _tex_cell(text: str, bold: bool) -> str:
    value, _, count = text.partition(" ")
    value = tex_escape(value)
    value = rf"\textbf{{{value}}}" if bold else value
    return rf"{value}\,{{\scriptsize {tex_escape(count)}}}" if count else value


def render_latex(aggregates: pd.DataFrame, spec: TableSpec) -> str:
    header, rows, best = text_rows(aggregates, spec)
    nkeys = len(spec.keys)
    lines = [r"\begin{table}[t]", r"\centering", r"\small",
             rf"\caption{{{tex_escape(spec.title)}. {tex_escape(legend(spec).replace('* most', 'Bold: most'))}.}}",
             r"\begin{tabular}{" + "l" * nkeys + "r" * len(spec.columns) + "}", r"\toprule",
             " & ".join(tex_escape(h) for h in header) + r" \\", r"\midrule"]
    for r, flags in zip(rows, best.itertuples(index=False)):
        cells = [tex_escape(c) for c in r[:nkeys]] + [_tex_cell(c, flag) for c, flag in zip(r[nkeys:], flags)]
        lines.append(" & ".join(cells) + r" \\")
    if not rows:
        lines.append(rf"\multicolumn{{{len(header)}}}{{c}}{{n/a (0 pairs)}} \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(lines)


def csv_frame(aggregates: pd.DataFrame, spec: TableSpec) -> pd.DataFrame:
    """Keys, then each column (built-ins in %, plugin metrics as they come) with its counts
    (``X_k``/``X_n`` for rates, ``X_n`` otherwise)."""
    out = pd.DataFrame({k: aggregates[k] for k in spec.keys}) if len(aggregates) else pd.DataFrame(columns=list(spec.keys))
    for column in spec.columns:
        values = aggregates[column.value].astype(float) if len(aggregates) else pd.Series([], dtype=float)
        out[column.label] = 100 * values if column.percent else values
        if column.k:
            out[f"{column.label}_k"] = aggregates[column.k] if len(aggregates) else pd.Series([], dtype=int)
        out[f"{column.label}_n"] = aggregates[column.n] if len(aggregates) else pd.Series([], dtype=int)
    return out
