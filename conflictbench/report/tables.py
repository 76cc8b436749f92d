"""The paper's three tables, built from aggregates, written with ``tabulate`` for the terminal,
Markdown and LaTeX, and as CSV.

Every metric column is shown as its registration says (:class:`~conflictbench.core.MetricSpec`),
built-ins and plugins alike: its label, its unit (``"%"``: a fraction shown as a percentage with
one decimal; any other unit after the value) and its direction. The outcome measures (PCSR,
RGSR, dSR, FR) are this report's own columns, rates in %. Each value carries its 95 % interval and its
counts: "68.8 [33.1, 90.7] (11/16)" for a rate, "76.5 [70.2, 82.0] (n=310)" for a mean over the pairs
where the measure is defined; an empty subset reads "n/a (0/0)" or "n/a (n=0)". Each row says how many
base tasks (the clusters its intervals rest on, :mod:`conflictbench.metrics.intervals`) its pairs come from.

In each column the most favourable value is marked (terminal "*", Markdown bold, LaTeX \\textbf)
among the rows of the same prompt condition (and family in the family table) only where a paired
comparison tells it apart from the runner-up (:mod:`.marking`); the note under the table names the
columns where none is. A metric's direction is its ``higher_is_better``;
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
from conflictbench.core.words import counted

from .paper import PAPER_FILES, beside_note, with_paper_rows

OUTCOME_DIRECTIONS = {"PCSR": "higher", "RGSR": "lower", "dSR": "higher", "FR": "higher"}
#: The paper's layout: which metrics (by name, in order) tables 1 and 3 and table 2 show first;
#: every other selected metric follows them.
PAPER_METRICS = ("tar", "early20_ts", "ts", "ams")
FAMILY_TABLE_METRICS = ("tar", "ts", "ams")
#: What the brackets and the tasks column of a table mean (README, "Uncertainty").
INTERVAL_NOTE = "[95 % interval] clustered by base task (tasks: how many the row's pairs come from)"
TEXT_INTERVAL_NOTE = "[95 % interval] clustered by base task (under the model: how many base tasks the pairs come from)"
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

    @property
    def measure(self) -> str:
        """The aggregate's name of the measure shown (its interval columns are ``<measure>_lo``, ``_hi``)."""
        return self.value


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


def candidates(aggregates: pd.DataFrame, spec: TableSpec) -> list[tuple[int, pd.Index, int | None]]:
    """Per column and block: (column position, the most favourable rows, the runner-up's row or None) where
    at least two rows have a value and they are not all equal (else nothing to tell apart)."""
    out: list[tuple[int, pd.Index, int | None]] = []
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
            if len(values) < 2 or values.nunique() == 1:
                continue
            ranked = values.sort_values(ascending=column.direction == "lower", kind="stable")
            best = ranked.index[ranked == ranked.iloc[0]]
            runner = None if len(best) > 1 else ranked.index[1]  # a tie for the best: nothing tells them apart
            out.append((j, best, runner))
    return out


def marks(aggregates: pd.DataFrame, spec: TableSpec, told_apart=None) -> tuple[pd.DataFrame, list[str]]:
    """Boolean frame (same index, one column per table column, by position): is this the most favourable
    value of its block, told apart from the runner-up (``told_apart(best_row, runner_row, column)``: a
    paired comparison, :mod:`.marking`; None: nothing is marked)? Also the labels of the columns where a block
    had a most favourable value that was not told apart (the note under the table names them)."""
    out = pd.DataFrame(False, index=aggregates.index, columns=range(len(spec.columns)))
    untold: list[str] = []
    for j, best, runner in candidates(aggregates, spec):
        column = spec.columns[j]
        if runner is not None and told_apart is not None and told_apart(best[0], runner, column):
            out.loc[best, j] = True
        elif column.label not in untold:
            untold.append(column.label)
    return out, untold


def _number(value: float, column: Column) -> str:
    return f"{100 * value:.1f}" if column.percent else f"{value:.4g}"


def cell_parts(row: pd.Series, column: Column) -> tuple[str, str, str]:
    """(value, interval, counts) of one cell: ("68.8", "[41.3, 89.0]", "(11/16)"), ("0.42 m", "[0.31, 0.5]",
    "(n=12)"), ("n/a", "", "(n=0)"); the interval "[n/a]" where none can be given (a measure without a range
    whose pairs all agree)."""
    value = row[column.value]
    n = _count(row, column.n)
    counts = f"({_count(row, column.k)}/{n})" if column.kind == "rate" else f"(n={n})"
    if not (_defined(value) and n):
        return "n/a", "", counts
    low, high = row.get(f"{column.measure}_lo"), row.get(f"{column.measure}_hi")
    shown = _number(value, column) + ("" if column.percent or not column.unit else f" {column.unit}")
    if low is None:  # aggregates without intervals
        return shown, "", counts
    interval = f"[{_number(low, column)}, {_number(high, column)}]" if _defined(low) and _defined(high) else "[n/a]"
    return shown, interval, counts


def _joined(*parts: str) -> str:
    return " ".join(part for part in parts if part)


def cell(row: pd.Series, column: Column) -> str:
    return _joined(*cell_parts(row, column))


def _key_text(value) -> str:
    return str(value) if _defined(value) else "-"


@dataclass(frozen=True)
class Marked:
    """Which values are marked most favourable (:func:`marks`), and the columns where a block's was not."""

    flags: pd.DataFrame
    untold: tuple[str, ...] = ()


def unmarked(aggregates: pd.DataFrame, spec: TableSpec) -> Marked:
    return Marked(pd.DataFrame(False, index=aggregates.index, columns=range(len(spec.columns))))


def _body(aggregates: pd.DataFrame, spec: TableSpec, marked: Marked | None) -> list[tuple[list[str], list[tuple]]]:
    """Per row: the key texts and its base tasks, and per column (value, interval, counts, is it marked)."""
    flags = (marked or unmarked(aggregates, spec)).flags
    return [
        (
            [_key_text(row[k]) for k in spec.keys] + [str(int(row["clusters"])) if "clusters" in row else "-"],
            [(*cell_parts(row, c), bool(flag)) for c, flag in zip(spec.columns, flags)],
        )
        for (_, row), flags in zip(aggregates.iterrows(), flags.itertuples(index=False))
    ]


def table_header(spec: TableSpec) -> list[str]:
    return [KEY_LABELS.get(k, k) for k in spec.keys] + ["tasks"] + [c.label for c in spec.columns]


def _alignment(spec: TableSpec) -> tuple[str, ...]:
    return ("left",) * len(spec.keys) + ("right",) * (1 + len(spec.columns))


def _placeholder(spec: TableSpec) -> list[str]:
    return ["n/a (0 pairs)"] + [""] * (len(spec.keys) + len(spec.columns))


def legend(spec: TableSpec, mark: str = "*") -> str:
    higher = [c.label for c in spec.columns if c.direction == "higher"]
    lower = [c.label for c in spec.columns if c.direction == "lower"]
    own_units = [c.label for c in spec.columns if not c.percent]
    within = " and ".join(BLOCK_WORDS.get(b, b) for b in spec.block) or "the table"
    parts = ([f"higher {', '.join(higher)}"] if higher else []) + ([f"lower {', '.join(lower)}"] if lower else [])
    units = "rates and means in %" + (f" except {', '.join(own_units)} (own units)" if own_units else "")
    return (
        f"{units}, {INTERVAL_NOTE}, counts in brackets; "
        f"{mark} most favourable per column within each {within} ({'; '.join(parts)}), where a paired comparison "
        "tells it apart from the runner-up at 5 %"
    )


def marks_note(spec: TableSpec, marked: Marked | None) -> list[str]:
    """The line under a table naming the columns whose most favourable value a paired comparison did not tell
    apart from the runner-up (none where every block had one row)."""
    if not marked or not marked.untold:
        return []
    within = " and ".join(BLOCK_WORDS.get(b, b) for b in spec.block) or "table"
    return [
        f"not marked: {', '.join(marked.untold)} (in some {within}, the most favourable value is not told apart "
        "from the runner-up by a paired comparison at 5 %)"
    ]


def table_rows(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None,
               marked: Marked | None = None):  # fmt: skip
    """The table's rows with the paper's beside the P0 rows of models declared as its (:mod:`.paper`)."""
    return with_paper_rows(_body(aggregates, spec, marked), spec, declared)


def paper_note(spec: TableSpec, declared: Mapping[str, str] | None) -> list[str]:
    return [note] if spec.name in PAPER_FILES and (note := beside_note(declared)) else []


def _notes(spec: TableSpec, declared: Mapping[str, str] | None, marked: Marked | None) -> list[str]:
    return [*marks_note(spec, marked), *paper_note(spec, declared)]


def render_text(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None = None,
                marked: Marked | None = None) -> str:  # fmt: skip
    """The terminal's table, each interval on a line under its value and the row's base tasks under its model;
    ``declared`` (model label -> the paper's model) adds the paper's rows beside;
    ``marked``: the most favourable values (:mod:`.marking`; None: none marked)."""
    if aggregates.empty:
        return f"== {spec.title} ==\nn/a: no pairs (0 pairs with both a conflict episode and its reference)"
    # the interval under the value, and the row's base tasks under its first key: a terminal's width holds the
    # paper's columns
    width = len(spec.keys)
    rows = [
        [keys[0] + ("" if keys[width] == "-" else f"\n{counted(int(keys[width]), 'task')}"), *keys[1:width]]
        + [_joined(value, counts) + ("*" if best else "") + (f"\n{interval}" if interval else "")
           for value, interval, counts, best in cells]
        for keys, cells in table_rows(aggregates, spec, declared, marked)
    ]  # fmt: skip
    header = [h for h in table_header(spec) if h != "tasks"]
    table = narrow_table(rows, header)
    text_legend = legend(spec).replace(INTERVAL_NOTE, TEXT_INTERVAL_NOTE)
    return "\n".join([f"== {spec.title} ==", table, text_legend, *_notes(spec, declared, marked)])


def narrow_table(rows: Sequence[Sequence[str]], header: Sequence[str]) -> str:
    """tabulate's "simple" table without the two spaces it adds to every header's width: the paper's columns,
    each with its interval, fit a terminal of about 110 characters."""
    import tabulate as module

    padding, module.MIN_PADDING = module.MIN_PADDING, 0
    try:
        return tabulate(rows, header, tablefmt="simple", disable_numparse=True)
    finally:
        module.MIN_PADDING = padding


def render_markdown(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None = None,
                    marked: Marked | None = None) -> str:  # fmt: skip
    rows = [
        keys + [f"**{_joined(v, i, c)}**" if best else _joined(v, i, c) for v, i, c, best in cells]
        for keys, cells in table_rows(aggregates, spec, declared, marked)
    ] or [_placeholder(spec)]
    rows = [[text.replace("|", r"\|") for text in row] for row in rows]  # a "|" would end the cell
    table = tabulate(rows, table_header(spec), tablefmt="pipe", colalign=_alignment(spec), disable_numparse=True)
    notes = _notes(spec, declared, marked)
    return "\n".join([f"### {spec.title}", "", table, "", legend(spec, "bold:"), *notes, ""])


# LaTeX markup travels through tabulate's escaping as private-use characters, replaced afterwards,
# so that tabulate escapes every text (keys, labels, values) and only our markup stays raw.
_BOLD, _END_BOLD, _SMALL, _END_SMALL = "\ue000", "\ue001", "\ue002", "\ue003"
_MARKUP = str.maketrans({_BOLD: r"\textbf{", _END_BOLD: "}", _SMALL: r"\,{\scriptsize ", _END_SMALL: "}"})


def tex_escape(text: str) -> str:
    """LaTeX's special characters escaped with tabulate's own rules (as in its ``latex`` formats)."""
    return "".join(LATEX_ESCAPE_RULES.get(ch, ch) for ch in text)


def _tex_cell(value: str, interval: str, counts: str, best: bool) -> str:
    if not value:  # a paper row's column the paper does not have
        return ""
    shown = f"{_BOLD}{value}{_END_BOLD}" if best else value
    small = " ".join(p for p in (interval, counts) if p)
    return f"{shown}{_SMALL}{small}{_END_SMALL}"


def render_latex(aggregates: pd.DataFrame, spec: TableSpec, declared: Mapping[str, str] | None = None,
                 marked: Marked | None = None) -> str:  # fmt: skip
    rows = [
        keys + [_tex_cell(*parts) for parts in cells] for keys, cells in table_rows(aggregates, spec, declared, marked)
    ] or [_placeholder(spec)]
    tabular = tabulate(
        rows, table_header(spec), tablefmt="latex_booktabs", colalign=_alignment(spec), disable_numparse=True
    ).translate(_MARKUP)
    notes = [f"{note}." for note in _notes(spec, declared, marked)]
    caption = tex_escape(" ".join([f"{spec.title}. {legend(spec, 'Bold:')}.", *notes]))
    return "\n".join(
        [r"\begin{table}[t]", r"\centering", r"\small", rf"\caption{{{caption}}}", tabular, r"\end{table}", ""]
    )


def csv_frame(aggregates: pd.DataFrame, spec: TableSpec) -> pd.DataFrame:
    """Keys and the row's base tasks (``tasks``), then each column (in % where its unit is "%", else as
    measured) with its 95 % interval (``X_lo``, ``X_hi``), its counts (``X_k``/``X_n`` for rates, ``X_n``
    otherwise) and the base tasks it rests on (``X_clusters``)."""
    empty = not len(aggregates)
    out = pd.DataFrame({k: aggregates[k] for k in spec.keys}) if not empty else pd.DataFrame(columns=list(spec.keys))
    out["tasks"] = aggregates["clusters"] if not empty else pd.Series([], dtype=int)
    for column in spec.columns:
        factor = 100 if column.percent else 1
        for suffix in ("", "_lo", "_hi"):
            name = f"{column.measure}{suffix}"
            values = aggregates[name].astype(float) if not empty else pd.Series([], dtype=float)
            out[f"{column.label}{suffix}"] = factor * values
        if column.k:
            out[f"{column.label}_k"] = aggregates[column.k] if not empty else pd.Series([], dtype=int)
        out[f"{column.label}_n"] = aggregates[column.n] if not empty else pd.Series([], dtype=int)
        clusters = f"{column.measure}_clusters"
        out[f"{column.label}_clusters"] = aggregates[clusters] if not empty else pd.Series([], dtype=int)
    return out
