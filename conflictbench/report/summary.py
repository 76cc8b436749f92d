"""The report printed at the end of a run and by ``conflictbench report DIR``.

From the episodes: pairs (episodes a simulator failure ended are left out, and said so; a policy
error counts as a failed episode), every metric per
pair through the fast path, aggregates per model/family/level/suite/case and prompt condition
with 95 % intervals clustered by base task, the paper's three tables (a value marked most favourable
only where a paired comparison tells it apart, :mod:`.marking`), paired P0 - P1 differences, and with
``out_dir`` the files:

- ``table1_overall``, ``table2_by_family``, ``table3_qualified_failures`` as ``.md``, ``.tex``
  and ``.csv`` (percentages with their intervals and counts), and ``report.md`` with all tables together;
- ``pairs.csv`` (one row per pair), ``aggregates_<grouping>.csv`` (fractions, intervals and counts),
  ``prompt_couples.csv`` and ``prompt_differences.csv`` when P0 and P1 episodes match;
- ``fig_qf_distributions.png``, ``fig_prompt_differences.png``, ``fig_dsr_heatmap.png``, ``fig_outcomes.png``.
"""

from __future__ import annotations

import re
import sys
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import pandas as pd

from conflictbench.core import ERROR_KINDS, EpisodeRecord, MetricSpec, Pair
from conflictbench.core.plugins import Plugins
from conflictbench.core.words import counted
from conflictbench.metrics import (
    GROUPINGS,
    aggregate,
    evaluate_pairs,
    make_pairs,
    metric_specs,
    prompt_couples,
    prompt_differences,
    with_model,
)
from conflictbench.metrics.measures import metric_ranges, report_measures
from conflictbench.store.paths import writable_folder

from .differences import render_prompt_differences
from .marking import paired_marks
from .paper import declared_labels
from .tables import (
    PAPER_METRICS,
    Marked,
    TableSpec,
    csv_frame,
    paper_order,
    paper_tables,
    render_latex,
    render_markdown,
    render_text,
)

TABLE_KEYS = {
    "table1_overall": "overall",
    "table2_by_family": "family",
    "table3_qualified_failures": "qualified_failures",
}


def select_metrics(plugins: Plugins, names: Sequence[str] | None) -> list[MetricSpec]:
    """The metrics a report shows: all (built-ins and registered), or those named (UserError if unknown)."""
    return metric_specs(plugins, names)


@dataclass
class EpisodeCounts:
    """What the report says about the episodes behind its pairs."""

    episodes: int = 0
    references: int = 0
    pairs: int = 0
    orphans: int = 0
    policy_errors: list[EpisodeRecord] = field(default_factory=list)
    crashed: list[EpisodeRecord] = field(default_factory=list)
    unserved: list[EpisodeRecord] = field(default_factory=list)
    """Episodes the serving infrastructure ended (a policy server's error reply, a broken connection)."""
    other_suites: Counter = field(default_factory=Counter)
    """Conflict episodes not shown, by the suite they are of (a report of one suite)."""
    unrecorded_suite: int = 0
    """Conflict episodes of a store written before the suite was recorded, shown as the reported suite's."""
    gone_cases: list[str] = field(default_factory=list)
    """Case ids of the episodes not shown that the reported suite no longer plays (new text, or removed)."""
    suite: str | None = None


def other_suites_line(other: Counter) -> str | None:
    """``412 conflict episode(s) of suite conflictvla 1.0.0 not shown ...``: what a report of one suite left out."""
    if not other:
        return None
    parts = ", ".join(f"{n} of suite {label}" for label, n in sorted(other.items()))
    return f"conflict episodes not shown: {parts} (conflictbench report --all-suites shows them)"


GONE_FILE = "cases_no_longer_in_suite.txt"


def gone_cases_line(counts: EpisodeCounts, out_dir: str | Path | None = None) -> str | None:
    """Which of the other suites' cases the reported suite no longer has: their episodes cannot be
    played again as they were (a case whose text is unchanged is played again under the new version)."""
    gone = counts.gone_cases
    if not gone:
        return None
    shown = ", ".join(gone[:5]) + (f" and {len(gone) - 5} more" if len(gone) > 5 else "")
    where = f" (all in {Path(out_dir) / GONE_FILE})" if out_dir is not None else ""
    return f"of them, {len(gone)} case(s) are no longer in suite {counts.suite}: {shown}{where}"


def left_out_line(episodes: Sequence[EpisodeRecord]) -> str | None:
    """``k left out: 2 server, 1 simulator``: the episodes something other than the policy ended, by whose failure."""
    if not episodes:
        return None
    by_kind = Counter(r.failure_kind for r in episodes)
    kinds = ", ".join(f"{by_kind[k]} {k}" for k in ERROR_KINDS if by_kind[k])
    first = episodes[0]
    return (
        f"{len(episodes)} episode(s) left out, with their pairs, and played again by the next run: {kinds} "
        f"(e.g. {first.episode_id}: {first.error})"
    )


def pair_up(
    records: Iterable[EpisodeRecord], suite: str | None = None, suite_cases: Iterable[str] | None = None
) -> tuple[list[Pair], EpisodeCounts]:
    """Pairs for the report. A policy error ends an episode as a failure (it stays in); a simulator or
    serving-infrastructure failure says nothing about the policy, so such episodes are left out with their pairs.
    With ``suite`` (``name version``), only that suite's conflict episodes, and the others counted; with
    ``suite_cases`` (the ids it plays), the cases of those others it no longer has are named."""
    records = list(records)
    other, unrecorded, gone = Counter(), 0, []
    if suite is not None:  # a store written before the column: its conflict episodes are shown, and said so
        conflicts = [r for r in records if not r.is_reference]
        hidden = [r for r in conflicts if r.conflict_suite not in (suite, None)]
        other = Counter(r.conflict_suite for r in hidden)
        if suite_cases is not None:
            playing = set(suite_cases)
            gone = sorted({r.case_id for r in hidden if r.case_id and r.case_id not in playing})
        unrecorded = sum(r.conflict_suite is None for r in conflicts)
        records = [r for r in records if r.is_reference or r.conflict_suite in (suite, None)]
    counts = EpisodeCounts(
        other_suites=other,
        unrecorded_suite=unrecorded,
        gone_cases=gone,
        suite=suite,
        episodes=len(records),
        references=sum(r.is_reference for r in records),
        policy_errors=[r for r in records if r.error is not None and not r.infrastructure_failed],
        crashed=[r for r in records if r.simulator_failed],
        unserved=[r for r in records if r.infrastructure_failed and not r.simulator_failed],
    )
    pairs, orphans = make_pairs(r for r in records if not r.infrastructure_failed)
    counts.pairs, counts.orphans = len(pairs), len(orphans)
    return pairs, counts


def report_records(
    records: Iterable[EpisodeRecord],
    plugins: Plugins,
    *,
    out_dir: str | Path | None = None,
    metrics: Sequence[str] | None = None,
    stream: TextIO | None = None,
    figures: bool = True,
    directions: Mapping[str, str] | None = None,
    paper: Mapping[tuple[str, str], str] | None = None,
    print_legend: bool = True,
) -> dict[str, pd.DataFrame]:
    """Print the tables for these episodes and, with ``out_dir``, write them and the figures.

    ``metrics`` restricts the columns (default: every registered metric); ``directions`` maps a
    metric or outcome name to "higher"/"lower", overriding the direction its registration gives
    (a metric registered without one is unmarked otherwise); ``paper`` and ``print_legend`` as :func:`report_frame`'s.
    Returns the frames by name: ``pairs``,
    ``overall``, ``family``, ``qualified_failures``, ``aggregates_<grouping>``, ``prompt_couples``,
    ``prompt_differences``.
    """
    chosen = select_metrics(plugins, metrics)
    pairs, counts = pair_up(records)
    frame = evaluate_pairs(
        [p.reference for p in pairs], [p.conflict for p in pairs], plugins=plugins, metrics=[m.name for m in chosen]
    )
    return report_frame(frame, counts, chosen, out_dir=out_dir, stream=stream, figures=figures, directions=directions,
                        paper=paper, print_legend=print_legend)  # fmt: skip


def report_frame(
    frame: pd.DataFrame,
    counts: EpisodeCounts,
    metrics: Sequence[MetricSpec],
    *,
    out_dir: str | Path | None = None,
    stream: TextIO | None = None,
    figures: bool = True,
    directions: Mapping[str, str] | None = None,
    paper: Mapping[tuple[str, str], str] | None = None,
    print_legend: bool = True,
) -> dict[str, pd.DataFrame]:
    """Everything after the per-pair frame: aggregates, tables, differences, files and figures.
    Each metric is shown as its registration says (label, unit, direction). ``paper`` maps a (policy, settings
    hash) declared to be one of the paper's checkpoints to the paper's model: its P0 rows get the paper's
    figures beside them (:mod:`.paper`), shown and never computed with. ``print_legend=False`` leaves the legend out of
    what is printed (the files keep it)."""
    stream = stream or sys.stdout
    metrics = paper_order(metrics)  # the differences table follows table 1's column order
    names = [m.name for m in metrics]
    ranges = metric_ranges(metrics)
    frame = with_model(frame)
    declared = declared_labels(frame, paper)
    aggregates = {grouping: aggregate(frame, by, names, ranges) for grouping, by in GROUPINGS.items()}
    specs = paper_tables(metrics, directions)
    measures = {m.name: m for m in report_measures(names, ranges)}
    marked = {s.name: paired_marks(frame, aggregates[s.grouping], s, measures) for s in specs}
    couples = prompt_couples(frame, names)
    differences = prompt_differences(couples, names, ranges=ranges)

    for spec in specs:
        print("\n" + render_text(aggregates[spec.grouping], spec, declared, marked[spec.name]), file=stream)
    if print_legend:  # a sweep's jobs leave it to the combined report, printed once
        print("\n" + legend(metrics), file=stream)
    if len(differences):
        print("\n" + render_prompt_differences(differences, metrics), file=stream)
    print(
        f"\n{counted(counts.episodes, 'episode')} ({counts.references} reference, "
        f"{counts.episodes - counts.references} conflict), {counted(counts.pairs, 'pair')}",
        file=stream,
    )
    if counts.policy_errors:
        first = counts.policy_errors[0]
        print(
            f"{len(counts.policy_errors)} episode(s) ended with a policy error and count as failed "
            f"(e.g. {first.episode_id}: {first.error})",
            file=stream,
        )
    if line := left_out_line(counts.crashed + counts.unserved):
        print(line, file=stream)
    if line := other_suites_line(counts.other_suites):
        print(line, file=stream)
    if line := gone_cases_line(counts, out_dir):
        print(line, file=stream)
    if counts.unrecorded_suite:
        print(f"{counts.unrecorded_suite} conflict episode(s) were stored before their suite was recorded and are "
              "shown as this suite's", file=stream)  # fmt: skip
    if counts.orphans:
        print(f"{counts.orphans} conflict episode(s) have no usable stored reference yet and are left out", file=stream)
    if (line := tar_undefined_line(frame, names)) is not None:
        print(line, file=stream)

    result = {
        "pairs": frame,
        **{TABLE_KEYS[s.name]: aggregates[s.grouping] for s in specs},
        **{f"aggregates_{g}": a for g, a in aggregates.items()},
        "prompt_couples": couples,
        "prompt_differences": differences,
    }
    if out_dir is not None:
        out = writable_folder(Path(out_dir), "the report")  # never through a link: a store is data (#42)
        out.mkdir(parents=True, exist_ok=True)
        write_files(out, frame, aggregates, specs, couples, differences, metrics, figures=figures, declared=declared,
                    marked=marked)  # fmt: skip
        if counts.gone_cases:
            (out / GONE_FILE).write_text("".join(f"{c}\n" for c in counts.gone_cases), encoding="utf-8")
        print(f"tables{' and figures' if figures else ''} written to {out}/", file=stream)
    return result


def write_files(
    out: Path,
    frame: pd.DataFrame,
    aggregates: dict[str, pd.DataFrame],
    specs: Sequence[TableSpec],
    couples: pd.DataFrame,
    differences: pd.DataFrame,
    metrics: Sequence[MetricSpec],
    *,
    figures: bool = True,
    declared: Mapping[str, str] | None = None,
    marked: Mapping[str, Marked] | None = None,
) -> list[Path]:
    written = []
    report = ["# conflictbench report", ""]
    marked = marked or {}
    for spec in specs:
        table = aggregates[spec.grouping]
        markdown = render_markdown(table, spec, declared, marked.get(spec.name))
        for suffix, text in ((".md", markdown), (".tex", render_latex(table, spec, declared, marked.get(spec.name)))):
            path = out / f"{spec.name}{suffix}"
            path.write_text(text)
            written.append(path)
        path = out / f"{spec.name}.csv"
        csv_frame(table, spec).to_csv(path, index=False, na_rep="n/a")
        written.append(path)
        report.append(markdown)
    report += ["### Legend", "", "```", legend(metrics), "```", ""]
    if (line := tar_undefined_line(frame, [m.name for m in metrics])) is not None:
        report += [line, ""]
    if len(differences):
        report += [
            "### Paired P0 - P1 differences (percentage points, 95 % intervals)",
            "",
            "```",
            render_prompt_differences(differences, metrics),
            "```",
            "",
        ]
    for grouping, table in aggregates.items():
        path = out / f"aggregates_{grouping}.csv"
        table.to_csv(path, index=False, na_rep="n/a")
        written.append(path)
    path = out / "pairs.csv"
    frame.to_csv(path, index=False, na_rep="n/a")
    written.append(path)
    if len(couples):
        for name, table in (("prompt_couples", couples), ("prompt_differences", differences)):
            path = out / f"{name}.csv"
            table.to_csv(path, index=False, na_rep="n/a")
            written.append(path)
    if figures:
        from . import figures as figs  # matplotlib is imported only when figures are drawn

        shown = [m for m in paper_order(metrics) if m.name in PAPER_METRICS]  # the paper's figures
        if shown:
            written.append(figs.qualified_failure_distributions(frame, out / "fig_qf_distributions.png", shown))
        written.append(figs.prompt_difference_figure(differences, out / "fig_prompt_differences.png", shown))
        written.append(figs.dsr_heatmap(aggregates["family_level"], out / "fig_dsr_heatmap.png"))
        written.append(figs.outcome_bars(aggregates["family_level"], out / "fig_outcomes.png"))
        report += ["## Figures", ""] + [f"![{p.stem}]({p.name})" for p in written if p.suffix == ".png"] + [""]
    path = out / "report.md"
    path.write_text("\n".join(report))
    written.append(path)
    return written


#: The outcome measures in a few words (the paper's definitions; README "Measures" has them whole).
OUTCOME_LEGEND = (
    ("PCSR", "the reference episodes that succeeded (original instruction)"),
    ("RGSR", "the conflict episodes that still completed the original goal"),
    ("dSR", "PCSR - RGSR"),
    ("FR", "qualified failures among the pairs whose reference succeeded"),
)


def legend(metrics) -> str:
    """What each column means, one short line each: the outcome measures, then every registered metric (its
    label and the gist of its description: after a leading "Name:", before a "(details)" or "; lower = ...")."""
    rows = list(OUTCOME_LEGEND)
    for metric in metrics:
        text = metric.description or ""
        head, colon, rest = text.partition(": ")
        gist = rest if colon and "(" not in head else text
        gist = re.split(r"; (?:lower|higher) =| \(", gist, maxsplit=1)[0]
        rows.append((metric.label or metric.name, gist.strip()))
    width = max(len(name) for name, _ in rows)
    return "Legend\n" + "\n".join(f"  {name.ljust(width)}  {text}" for name, text in rows)


def tar_undefined_line(frame: pd.DataFrame, names: Sequence[str]) -> str | None:
    """How many pairs TAR leaves undefined, where any are, by cause (None otherwise)."""
    if "tar" not in names or not len(frame) or not (undefined := int(frame["tar"].isna().sum())):
        return None
    same = frame["same_targets"].astype(bool) if "same_targets" in frame.columns else pd.Series(True, frame.index)
    other_targets = int((frame["tar"].isna() & ~same).sum())
    causes = [
        *([f"{undefined - other_targets} whose reference approached its targets by less than 1 cm (a ratio to that "
           "is noise)"] if undefined - other_targets else []),
        *([f"{other_targets} whose two rollouts have other targets"] if other_targets else []),
    ]  # fmt: skip
    return f"TAR is undefined for {undefined} of {len(frame)} pairs: " + "; ".join(causes)
