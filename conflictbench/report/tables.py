"""The paper's three tables, built from aggregates, written with ``tabulate`` for the terminal,
Markdown and LaTeX, and as CSV.

Every metric column is shown as its registration says (:class:`~conflictbench.core.MetricSpec`),
built-ins and plugins alike: its label, its unit (``"%"``: a fraction shown as a percentage with
one decimal; any other unit after the value) and its direction. The outcome measures (PCSR,
RGSR, dSR, FR) are this report's own columns, rates in %. Each value carries its counts:
"78.7 (315/400)" for a rate, "76.5 (n=310)" for a mean over the pairs where the measure is
defined; an empty subset reads "n/a (0/0)" or "n/a (n=0)".

In each column the most favourable value is marked (terminal "*", Markdown bold, LaTeX \\textbf)
among the rows of the same prompt condition (and family in the family table), when at least two
rows have a value and they are not all equal. A metric's direction is its ``higher_is_better``;
for the outcome measures (:data:`OUTCOME_DIRECTIONS`), a more capable policy has a higher PCSR,
and a better conflict response has a lower RGSR and a higher dSR and FR (its success dropped
under the conflict, it left the original goal undone when it was able to do it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import pandas as pd
from tabulate import LATEX_ESCAPE_RULES, tabulate

from conflictbench.core import MetricSpec

from .paper import PAPER_FILES, beside_note, with_paper_rows

OUTCOME_DIRECTIONS = {"PCSR": "higher", "RGSR": "lower", "dSR": "higher", "FR": "higher"}
#: The paper's layout: which metrics (by name, in order) tables 1 and 3 and table 2 show first;
#: every other selected metric follows them.
PAPER_METRICS = ("tar", "early20_ts", "ts", "ams")
FAMILY_TABLE_METRICS = ("tar", "ts", "ams")
KEY_LABELS = {"model": "model", "prompt": "prompt", "family": "family"}
BLOCK_WORDS = {"prompt": "prompt condition", "family": "family"}


@dataclass(frozen=True)
class Column:
    label: str
    kind: str  # "rate" (value with k/n), "diff" (dSR, with n), "mean" (with n)
    value: str  # aggregate column holding the value (a fraction when the unit is "%")
    k: str | None = None
    n: str = "pairs"
    direction: str | None = None
    unit: str = "%"

    @property
    def percent(self) -> bool:
        return self.unit == "%"


@dataclass(frozen=True)
class TableSpec:
    name: str
    title: str
    grouping: str  # key of conflictbench.metrics.GROUPINGS
    keys: tuple[str, ...]
    block: tuple[str, ...]  # rows compared with each other when marking the most favourable value
    columns: tuple[Column, ...]


def _metric_column(spec: MetricSpec, qualified_failures: bool, directions: Mapping[str, str]) -> Column:
    suffix = "_qf" if qualified_failures else ""
    return Column(
        spec.label,
        "mean",
        f"{spec.name}{suffix}",
        n=f"{spec.name}{suffix}_n",
        direction=directions.get(spec.name, spec.direction),
        unit=spec.unit,
    )


def paper_order(metrics: Sequence[MetricSpec]) -> list[MetricSpec]:
    """The paper's metrics in its column order, then every other one in the order given."""
    by_name = {m.name: m for m in metrics}
    return [by_name[n] for n in PAPER_METRICS if n in by_name] + [m for m in metrics if m.name not in PAPER_METRICS]


def paper_tables(metrics: Sequence[MetricSpec], directions: Mapping[str, str] | None = None) -> list[TableSpec]:
    """Table 1 (overall), 2 (by family) and 3 (FR and means over qualified failures), as in the paper,
    with every other selected metric appended. ``directions`` (name -> "higher"/"lower") overrides."""
    directions = directions or {}
    d = {**OUTCOME_DIRECTIONS, **directions}
    outcome = (
        Column("PCSR", "rate", "PCSR", k="PCSR_k", direction=d["PCSR"]),
        Column("RGSR", "rate", "RGSR", k="RGSR_k", direction=d["RGSR"]),
        Column("dSR", "diff", "dSR", direction=d["dSR"]),
    )
    by_name = {m.name: m for m in metrics}
    extra = [m for m in metrics if m.name not in PAPER_METRICS]

    def columns(layout: Sequence[str], qualified_failures: bool = False) -> tuple[Column, ...]:
        chosen = [by_name[n] for n in layout if n in by_name] + extra
        return tuple(_metric_column(m, qualified_failures, directions) for m in chosen)

    failures = (Column("FR", "rate", "FR", k="FR_k", n="FR_n", direction=d["FR"]),)
    return [
        TableSpec(
            "table1_overall",
            "Table 1: overall outcome and process measures",
            "model",
            ("model", "prompt"),
            ("prompt",),
            outcome + columns(PAPER_METRICS),
        ),
        TableSpec(
            "table2_by_family",
            "Table 2: by conflict family",
            "family",
            ("model", "prompt", "family"),
            ("prompt", "family"),
            outcome + columns(FAMILY_TABLE_METRICS),
        ),
        TableSpec(
            "table3_qualified_failures",
            "Table 3: failure rate among qualified pairs (FR) and process measures over the qualified failures D_QF",
            "model",
            ("model", "prompt"),
            ("prompt",),
            failures + columns(PAPER_METRICS, qualified_failures=True),
        ),
    ]


def _defined(value) -> bool:
    return value is not None and not (isinstance(value, float) and math.isnan(value))


def _count(row: pd.Series, column: str | None) -> int:
    return int(row[column]) if column and _defined(row[column]) else 0


def marks(aggregates: pd.DataFrame, spec: TableSpec) -> pd.DataFrame:
    """Boolean frame (same index, one column per table column, by position): is this the most favourable
    value of its block?"""
    out = pd.DataFrame(False, index=aggregates.index, columns=range(len(spec.columns)))
    if aggregates.empty:
        return out
    blocks = (
        [sub.index for _, sub in aggregates.groupby(list(spec.block), dropna=False, sort=False)]
        if spec.block
        else [aggregates.index]
    )
    for j, column in enumerate(spec.columns):
        if column.direction not in ("higher", "lower"):
            continue
        for index in blocks:
            values = aggregates.loc[index, column.value].astype(float)
            counts = aggregates.loc[index, column.n].astype(float)
            values = values[values.notna() & (counts > 0)]
            if len(values) < 2 or values.nunique() == 1:  # nothing to tell apart
                continue
            best = values.max() if column.direction == "higher" else values.min()
            out.loc[values.index[values == best], j] = True
    return out


def cell_parts(row: pd.Series, column: Column) -> tuple[str, str]:
    """(value, counts) of one cell: ("78.7", "(315/400)"), ("0.42 m", "(n=12)"), ("n/a", "(n=0)")."""
    value = row[column.value]
    n = _count(row, column.n)
    if column.kind == "rate":
        k = _count(row, column.k)
        return (f"{100 * value:.1f}" if _defined(value) and n else "n/a"), f"({k}/{n})"
    if not (_defined(value) and n):
        return "n/a", f"(n={n})"
    if column.percent:
        return f"{100 * value:.1f}", f"(n={n})"
    return f"{value:.4g}{f' {column.unit}' if column.unit else ''}", f"(n={n})"


def cell(row: pd.Series, column: Column) -> str:
    return " ".join(cell_parts(row, column))


def _key_text(value) -> str:
    return str(value) if _defined(value) else "-"


def _body(aggregates: pd.DataFrame, spec: TableSpec) -> list[tuple[list[str], list[tuple[str, str, bool]]]]:
    """Per row: the key texts, and per column (value, counts, is it the most favourable)."""
    best = marks(aggregates, spec)
    return [
        (
            [_key_text(row[k]) for k in spec.keys],
            [(*cell_parts(row, c), bool(flag)) for c, flag in zip(spec.columns, flags)],
        )
        for (_, row), flags in zip(aggregates.iterrows(), best.itertuples(index=False))
    ]


def table_header(spec: TableSpec) -> list[str]:
    return [KEY_LABELS.get(k, k) for k in spec.keys] + [c.label for c in spec.columns]


def _alignment(spec: TableSpec) -> tuple[str, ...]:
    return ("left",) * len(spec.keys) + ("right",) * len(spec.columns)


def _placeholder(spec: TableSpec) -> list[str]:
    return ["n/a (0 pairs)"] + [""] * (len(spec.keys) + len(spec.columns) - 1)


def legend(spec: TableSpec, mark: str = "*") -> str:
    higher = [c.label for c in spec.columns if c.direction == "higher"]
    lower = [c.label for c in spec.columns if c.direction == "lower"]
    own_units = [c.label for c in spec.columns if not c.percent]
    within = " and ".join(BLOCK_WORDS.get(b, b) for b in spec.block) or "the table"
    parts = ([f"higher {', '.join(higher)}"] if higher else []) + ([f"lower {', '.join(lower)}"] if lower else [])
    units = "rates and means in %" + (f" except {', '.join(own_units)} (own units)" if own_units else "")
    return f"{units}, counts in brackets; {mark} most favourable per column within each {within} ({'; '.join(parts)})"


def table_rows(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None):
    """The table's rows with the paper's beside the P0 rows of models declared as its (:mod:`.paper`)."""
    return with_paper_rows(_body(aggregates, spec), spec, declared)


def paper_note(spec: TableSpec, declared: Mapping[str, str] | None) -> list[str]:
    return [note] if spec.name in PAPER_FILES and (note := beside_note(declared)) else []


def render_text(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None = None) -> str:
    """The terminal's table; ``declared`` (model label -> the paper's model) adds the paper's rows beside."""
    if aggregates.empty:
        return f"== {spec.title} ==\nn/a: no pairs (0 pairs with both a conflict episode and its reference)"
    rows = [
        keys + [f"{value} {counts}{'*' if best else ''}".strip() for value, counts, best in cells]
        for keys, cells in table_rows(aggregates, spec, declared)
    ]
    table = tabulate(rows, table_header(spec), tablefmt="simple", disable_numparse=True)
    return "\n".join([f"== {spec.title} ==", table, legend(spec), *paper_note(spec, declared)])


def render_markdown(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None = None) -> str:
    rows = [
        keys + [f"**{value} {counts}**" if best else f"{value} {counts}".strip() for value, counts, best in cells]
        for keys, cells in table_rows(aggregates, spec, declared)
    ] or [_placeholder(spec)]
    rows = [[text.replace("|", r"\|") for text in row] for row in rows]  # a "|" would end the cell
    table = tabulate(rows, table_header(spec), tablefmt="pipe", colalign=_alignment(spec), disable_numparse=True)
    return "\n".join([f"### {spec.title}", "", table, "", legend(spec, "bold:"), *paper_note(spec, declared), ""])


# LaTeX markup travels through tabulate's escaping as private-use characters, replaced afterwards,
# so that tabulate escapes every text (keys, labels, values) and only our markup stays raw.
_BOLD, _END_BOLD, _SMALL, _END_SMALL = "\ue000", "\ue001", "\ue002", "\ue003"
_MARKUP = str.maketrans({_BOLD: r"\textbf{", _END_BOLD: "}", _SMALL: r"\,{\scriptsize ", _END_SMALL: "}"})


def tex_escape(text: str) -> str:
    """LaTeX's special characters escaped with tabulate's own rules (as in its ``latex`` formats)."""
    return "".join(LATEX_ESCAPE_RULES.get(ch, ch) for ch in text)


def _tex_cell(value: str, counts: str, best: bool) -> str:
    if not value:  # a paper row's column the paper does not have
        return ""
    shown = f"{_BOLD}{value}{_END_BOLD}" if best else value
    return f"{shown}{_SMALL}{counts}{_END_SMALL}"


def render_latex(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None = None) -> str:
    rows = [
        keys + [_tex_cell(*parts) for parts in cells] for keys, cells in table_rows(aggregates, spec, declared)
    ] or [_placeholder(spec)]
    tabular = tabulate(
        rows, table_header(spec), tablefmt="latex_booktabs", colalign=_alignment(spec), disable_numparse=True
    ).translate(_MARKUP)
    notes = [f"{note}." for note in paper_note(spec, declared)]
    caption = tex_escape(" ".join([f"{spec.title}. {legend(spec, 'Bold:')}.", *notes]))
    return "\n".join(
        [r"\begin{table}[t]", r"\centering", r"\small", rf"\caption{{{caption}}}", tabular, r"\end{table}", ""]
    )


def csv_frame(aggregates: pd.DataFrame, spec: TableSpec) -> pd.DataFrame:
    """Keys, then each column (in % where its unit is "%", else as measured) with its counts
    (``X_k``/``X_n`` for rates, ``X_n`` otherwise)."""
    out = (
        pd.DataFrame({k: aggregates[k] for k in spec.keys})
        if len(aggregates)
        else pd.DataFrame(columns=list(spec.keys))
    )
    for column in spec.columns:
        values = aggregates[column.value].astype(float) if len(aggregates) else pd.Series([], dtype=float)
        out[column.label] = 100 * values if column.percent else values
        if column.k:
            out[f"{column.label}_k"] = aggregates[column.k] if len(aggregates) else pd.Series([], dtype=int)
        out[f"{column.label}_n"] = aggregates[column.n] if len(aggregates) else pd.Series([], dtype=int)
    return out
