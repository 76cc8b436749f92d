"""The paper's own figures beside a run's: tables 1-3 of ConflictVLA-Bench (P0), shipped as cited data.

They are shown only for a model whose checkpoint the user declared to be one of the paper's eight official ones
(``model.published=<entry>``, an entry whose ``paper_model`` names the paper's row), and only beside that model's
P0 rows: a tiny or fine-tuned model never sits beside the paper's numbers. They are marked as the paper's, read
from the files in ``paper_data/`` and never enter a computation (no aggregate, mark or difference sees them). The
paper's suite is not this one: same definitions, other cases, which the one-line note under each table says.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from importlib import resources

import pandas as pd

from conflictbench.core import PluginError

PAPER_TITLE = (
    "ConflictVLA-Bench: Benchmarking Behavioral Responses of Vision-Language-Action Models to Premise Conflicts"
)
PAPER_CITATION = f'"{PAPER_TITLE}", tables 1-3, prompt condition P0'
#: Our table (``TableSpec.name``) -> the paper's table, as shipped.
PAPER_FILES = {
    "table1_overall": "table1_overall_p0.csv",
    "table2_by_family": "table2_by_family_p0.csv",
    "table3_qualified_failures": "table3_qualified_failures_p0.csv",
}
#: The aggregate a column shows (``Column.value``, ``_qf`` for the means over qualified failures) -> the paper's
#: column. A metric the paper does not have (a plugin's) gets no paper figure.
PAPER_COLUMNS = {"PCSR": "PCSR", "RGSR": "RGSR", "dSR": "dSR", "FR": "FR", "tar": "TAR", "early20_ts": "Early20_TS",
                 "ts": "TS", "ams": "AMS"}  # fmt: skip
#: The prompt condition the paper's tables report.
PAPER_PROMPT = "p0"
PAPER_ROW_LABEL = "paper: {model}"
PAPER_COUNTS = "(paper)"


@functools.cache
def paper_table(table: str) -> pd.DataFrame:
    """One of the paper's tables (values in %) by our table's name."""
    with (resources.files("conflictbench.report") / "paper_data" / PAPER_FILES[table]).open(encoding="utf-8") as f:
        return pd.read_csv(f)


def paper_models() -> tuple[str, ...]:
    """The paper's eight models, as its tables name them (what a published entry's ``paper_model`` may say)."""
    return tuple(str(m) for m in paper_table("table1_overall")["model"])


def paper_value(table: str, model: str, column_value: str, family: str | None = None) -> float | None:
    """The paper's figure (in %) for our column ``column_value`` of ``model`` (and ``family`` in table 2)."""
    column = PAPER_COLUMNS.get(column_value.removesuffix("_qf"))
    frame = paper_table(table)
    if column is None or column not in frame.columns:
        return None
    rows = frame[frame["model"] == model]
    if family is not None and "family" in frame.columns:
        rows = rows[rows["family"] == family]
    if len(rows) != 1 or pd.isna(rows.iloc[0][column]):
        return None
    return float(rows.iloc[0][column])


def with_paper_rows(
    body: Sequence[tuple[list[str], list[tuple[str, str, str, bool]]]],
    spec,
    declared: Mapping[str, str] | None,
) -> list[tuple[list[str], list[tuple[str, str, str, bool]]]]:
    """The table's rows (``tables._body``: keys, then the row's base tasks; cells (value, interval, counts,
    marked)), each P0 row of a declared model followed by the paper's row for it.

    ``declared`` maps a model's label in the report to the paper's model name. A paper row's cells carry
    ``(paper)`` where a row of ours carries its counts, no interval (the paper gives no counts to derive one
    from) and no base tasks, and are never marked most favourable."""
    if not declared or spec.name not in PAPER_FILES:
        return list(body)
    key_index = {key: i for i, key in enumerate(spec.keys)}
    out = []
    for keys, cells in body:
        out.append((keys, cells))
        model = declared.get(keys[key_index["model"]])
        if model is None or keys[key_index["prompt"]] != PAPER_PROMPT:
            continue
        family = keys[key_index["family"]] if "family" in key_index else None
        paper_keys = [PAPER_ROW_LABEL.format(model=model) if k == "model" else keys[i] for i, k in enumerate(spec.keys)]
        paper_keys += ["-"] * (len(keys) - len(spec.keys))
        paper_cells = []
        for column in spec.columns:
            value = paper_value(spec.name, model, column.value, family)
            paper_cells.append((f"{value:.1f}", "", PAPER_COUNTS, False) if value is not None else ("", "", "", False))
        out.append((paper_keys, paper_cells))
    return out


def beside_note(declared: Mapping[str, str] | None) -> str | None:
    """The one line under a table that shows the paper's rows (None where it shows none)."""
    if not declared:
        return None
    pairs = ", ".join(f"{label} as {model}" for label, model in sorted(declared.items()))
    return (
        f"paper: rows of the ConflictVLA-Bench paper (tables 1-3, P0) beside the checkpoints declared as its ({pairs}):"
        " same definitions, other cases (the paper's suite is not this one); shown, never computed with, and without"
        " an interval (the paper gives no counts)"
    )


def declared_labels(frame: pd.DataFrame, declared: Mapping[tuple[str, str], str] | None) -> dict[str, str]:
    """Model label -> the paper's model, for the models of ``frame`` (pairs with ``model``, ``policy`` and
    ``config_hash``) whose (policy, settings hash) ``declared`` maps to one of the paper's models."""
    if frame.empty or not declared:
        return {}
    known = set(paper_models())
    keys = frame[["policy", "config_hash", "model"]].drop_duplicates().itertuples(index=False)
    return {str(label): model for policy, config_hash, label in keys
            if (model := declared.get((str(policy), str(config_hash)))) in known}  # fmt: skip


def check_paper_model(result) -> None:
    """A :class:`PluginError` (one line) unless the published result's ``paper_model`` is None or one of
    :func:`paper_models`: the paper's names are this data's, so they are checked where the paper is read."""
    model = getattr(result, "paper_model", None)
    if model is not None and model not in paper_models():
        raise PluginError(
            f"published result {result.name!r} of {result.plugin} {result.plugin_version}: paper_model must be one of"
            f" {', '.join(paper_models())}, got {model!r}"
        )


def declared_paper_models(declarations: Mapping[tuple[str, str], str], published: Mapping[str, object]) -> dict:
    """(policy, settings hash) -> the paper's model, for the declarations (-> a published entry's name) of
    entries that are one of the paper's checkpoints (their ``paper_model``, checked: :func:`check_paper_model`)."""
    out = {}
    for key, entry in declarations.items():
        result = published.get(entry)
        check_paper_model(result)
        if (model := getattr(result, "paper_model", None)) is not None:
            out[key] = str(model)
    return out
