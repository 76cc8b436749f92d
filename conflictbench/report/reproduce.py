"""Does a checkpoint score what its authors published? Per suite: the measured success with its 95 % Wilson
interval beside the published figure, and a verdict."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from conflictbench.core import LIBERO_SUITES, EpisodeRecord
from conflictbench.core.registry import PublishedResult
from conflictbench.store.paths import writable_folder

Z95 = 1.959964
DECISIVE_HALF_WIDTH = 0.10
"""An interval wider than +/- 10 points decides nothing: the verdict is then ``inconclusive``."""
VERDICTS = ("consistent", "below", "above", "inconclusive")


def _bounds(rate: float, trials: int, z: float = Z95) -> tuple[float, float]:
    denominator = 1 + z * z / trials
    centre = (rate + z * z / (2 * trials)) / denominator
    half = z * math.sqrt(rate * (1 - rate) / trials + z * z / (4 * trials * trials)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def _half_width(rate: float, trials: int) -> float:
    low, high = _bounds(rate, trials)
    return (high - low) / 2


def wilson(successes: int, trials: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (fractions); (0, 1) without trials."""
    return (0.0, 1.0) if trials == 0 else _bounds(successes / trials, trials, z)


def verdict(successes: int, trials: int, published_percent: float) -> str:
    """``inconclusive`` when the interval's half-width exceeds 10 points; else ``consistent`` when the published
    figure lies inside it, ``below`` when the measured success is below it (the interval's top under the
    published figure), ``above`` otherwise."""
    low, high = wilson(successes, trials)
    if trials == 0 or (high - low) / 2 > DECISIVE_HALF_WIDTH:
        return "inconclusive"
    published = published_percent / 100
    if low <= published <= high:
        return "consistent"
    return "below" if high < published else "above"


def trials_to_decide(successes: int, trials: int, published_percent: float) -> int:
    """The fewest trials whose Wilson half-width at the observed rate (the published one where none was
    observed) is at most 10 points."""
    rate = successes / trials if trials else published_percent / 100
    n = 1
    while _half_width(rate, n) > DECISIVE_HALF_WIDTH:
        n += 1
    return n


@dataclass(frozen=True)
class SuiteRow:
    suite: str
    episodes: int
    successes: int
    left_out: int
    """Episodes the infrastructure failed (simulator, server): they say nothing about the policy."""
    published: float
    max_steps: tuple[int, ...]
    warmup_steps: tuple[int, ...]

    @property
    def interval(self) -> tuple[float, float]:
        return wilson(self.successes, self.episodes)

    @property
    def measured(self) -> float:
        return 100 * self.successes / self.episodes if self.episodes else math.nan

    @property
    def verdict(self) -> str:
        return verdict(self.successes, self.episodes, self.published)

    @property
    def to_decide(self) -> int:
        return trials_to_decide(self.successes, self.episodes, self.published)


def suite_rows(records: Iterable[EpisodeRecord], entry: PublishedResult) -> list[SuiteRow]:
    """One row per suite the entry publishes and the run played (reference episodes only)."""
    by_suite: dict[str, list[EpisodeRecord]] = {}
    for record in records:
        if record.is_reference and record.suite in entry.success:
            by_suite.setdefault(record.suite, []).append(record)
    rows = []
    for suite in [s for s in LIBERO_SUITES if s in by_suite]:
        played = by_suite[suite]
        kept = [r for r in played if not r.infrastructure_failed]
        rows.append(
            SuiteRow(
                suite, len(kept), sum(bool(r.success) for r in kept), len(played) - len(kept),
                entry.success[suite], tuple(sorted({r.max_steps for r in kept})),
                tuple(sorted({r.warmup_steps for r in kept if r.warmup_steps is not None})),
            )
        )  # fmt: skip
    return rows


def protocol_differences(rows: list[SuiteRow], entry: PublishedResult) -> list[str]:
    """Where this run's protocol is not the one behind the published figures."""
    protocol, notes = entry.protocol, []
    per_task = protocol.get("trials_per_task")
    seeds = protocol.get("seeds", 1)
    published_n = protocol["episodes_per_suite"]
    for row in rows:
        if row.episodes != published_n * seeds:
            basis = f"{seeds} seeds x {published_n}" if seeds > 1 else f"{published_n}"
            notes.append(f"{row.suite}: {row.episodes} episodes here; the published figure used {basis}"
                         + (f" ({per_task} per task)" if per_task else ""))  # fmt: skip
        steps = protocol.get("max_steps", {}).get(row.suite)
        if steps is not None and row.max_steps and row.max_steps != (steps,):
            here = "/".join(map(str, row.max_steps))
            notes.append(f"{row.suite}: step budget {here} here, {steps} in the published protocol")
    warmup = protocol.get("warmup_steps")
    here_warmup = sorted({w for row in rows for w in row.warmup_steps})
    if warmup is not None and here_warmup and here_warmup != [warmup]:
        notes.append(f"warm-up {'/'.join(map(str, here_warmup))} steps here, {warmup} in the published protocol")
    return notes


COLUMNS = ["suite", "episodes", "successes", "left_out", "measured_pct", "low_pct", "high_pct", "published_pct",
           "verdict", "trials_to_decide"]  # fmt: skip


def _cells(row: SuiteRow) -> list:
    low, high = row.interval
    return [row.suite, row.episodes, row.successes, row.left_out, round(row.measured, 1), round(100 * low, 1),
            round(100 * high, 1), row.published, row.verdict, row.to_decide]  # fmt: skip


def render(rows: list[SuiteRow], entry: PublishedResult) -> str:
    """The terminal table, then the citation, the caveats and the protocol differences."""
    lines = [f"reproduce {entry.name}: {entry.policy}, {entry.checkpoint}", ""]
    header = f"{'suite':<15} {'episodes':>8} {'successes':>9}  {'measured % [95% CI]':<22} {'published %':>11}  verdict"
    lines += [header, "-" * len(header)]
    for row in rows:
        low, high = row.interval
        counts = f" ({entry.counts[row.suite]})" if entry.counts and row.suite in entry.counts else ""
        measured = f"{row.measured:5.1f} [{100 * low:5.1f}, {100 * high:5.1f}]" if row.episodes else "-"
        lines.append(
            f"{row.suite:<15} {row.episodes:>8} {row.successes:>9}  {measured:<22} {row.published:>11g}  {row.verdict}"
            + counts
        )
    for row in rows:
        if row.verdict == "inconclusive":
            lines.append(f"{row.suite}: inconclusive; {row.to_decide} trials per suite would decide")
        if row.left_out:
            lines.append(f"{row.suite}: {row.left_out} episode(s) left out: the infrastructure, not the policy, failed")
    lines += ["", f"published: {entry.citation}" + (" [secondary only]" if entry.status == "secondary" else "")]
    lines += [f"caveat: {c}" for c in entry.caveats]
    lines += [f"protocol difference: {d}" for d in protocol_differences(rows, entry)]
    return "\n".join(lines) + "\n"


def write_report(rows: list[SuiteRow], entry: PublishedResult, report_dir: Path) -> tuple[Path, Path]:
    """``reproduce-<entry>.md`` (the table as text) and ``.csv`` (one row per suite) under ``report_dir``."""
    writable_folder(report_dir, "the reproduce report").mkdir(parents=True, exist_ok=True)  # no link followed, #42
    md, table = report_dir / f"reproduce-{entry.name}.md", report_dir / f"reproduce-{entry.name}.csv"
    md.write_text(f"# Reproduce {entry.name}\n\n```\n{render(rows, entry)}```\n", encoding="utf-8")
    buffer = io.StringIO()
    writer = csv.writer(buffer)
    writer.writerow(COLUMNS)
    writer.writerows(_cells(row) for row in rows)
    table.write_text(buffer.getvalue(), encoding="utf-8")
    return md, table
