"""What the intervals cost the report: the report of a paper-sized store, with and without them, side by side.

    .venv/bin/python benchmarks/report_intervals.py               # 8 models x 2 prompts x every case x 5 states
    .venv/bin/python benchmarks/report_intervals.py --models 2    # a quicker run

The store is synthetic, with the shipped suite's layout (every case of its base task, 5 initial states, both
prompts: 17,350 pairs a model, 138,800 for 8) and per-pair outcomes and measures drawn at random (NaN where TAR
would be undefined). What is timed is everything the report does after the per-pair measures: aggregates per
model, family, level, family x level, LIBERO suite and case, the three tables in every format, the P0 - P1
differences, the most-favourable marks, every file and figure. The per-pair process measures cost the same
with or without intervals (benchmarks/bench_metrics.py times them), so the whole report's ratio is smaller than
this one. "Without" replaces the interval machinery by point estimates only: the ratios of sums, no variance, no
interval, no paired test for the marks. Each is run ``--repeat`` times, alternating; the best of each is kept.
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
from contextlib import ExitStack
from unittest import mock

import numpy as np
import pandas as pd

import conflictbench
from conflictbench.metrics import intervals as interval_module
from conflictbench.metrics import measures, paired
from conflictbench.report import summary
from conflictbench.report.summary import EpisodeCounts, report_frame, select_metrics
from conflictbench.report.tables import unmarked
from conflictbench.tasks.suite.file import load_suite


def synthetic_frame(models: int, seed: int = 0) -> pd.DataFrame:
    cases = [c for c in load_suite(None).accepted()]
    rng = np.random.default_rng(seed)
    rows = []
    for m in range(models):
        for prompt in ("p0", "p1"):
            for case in cases:
                for state in range(5):
                    rows.append((f"model{m}", f"h{m}", case.suite, case.task_id, state, prompt, case.case_id,
                                 case.family, case.level))  # fmt: skip
    frame = pd.DataFrame(rows, columns=["policy", "config_hash", "suite", "task_id", "init_state", "prompt",
                                        "case_id", "family", "level"])  # fmt: skip
    n = len(frame)
    frame["policy_settings"] = ""
    frame["seed"] = 7
    frame["max_steps"] = 0
    frame["conflict_suite"] = "conflictvla 2.1.0"
    task_effect = frame.groupby(["policy", "suite", "task_id"]).ngroup().to_numpy()
    skill = rng.normal(size=task_effect.max() + 1)[task_effect]
    frame["reference_success"] = skill + rng.normal(size=n) * 0.5 > -0.3
    frame["conflict_success"] = skill + rng.normal(size=n) > 0.8
    frame["reference_episode"] = [f"r{i}" for i in range(n)]
    frame["conflict_episode"] = [f"c{i}" for i in range(n)]
    frame["same_targets"] = True
    for name in ("tar", "early20_ts", "ts", "ams"):
        frame[name] = rng.random(n)
    frame.loc[rng.random(n) < 0.05, "tar"] = np.nan
    return frame


def point_only(frame, by, chosen, suffixes=("",), **_):
    """The measures' values per group, nothing else (what the report computed before it had intervals)."""
    group, keys = measures.group_index(frame, by)
    out = keys.copy()
    out["clusters"] = 0
    for measure in chosen:
        value = np.zeros(len(keys))
        for sign, term, *side in measure.terms:
            suffix = suffixes[side[0] if side else 0]
            total = np.bincount(group, term.weight(frame, suffix), minlength=len(keys))
            with np.errstate(invalid="ignore", divide="ignore"):
                value += sign * np.bincount(group, term.numerator(frame, suffix), minlength=len(keys)) / total
        out[measure.name] = value
        for suffix in ("_lo", "_hi"):
            out[f"{measure.name}{suffix}"] = np.nan
        out[f"{measure.name}_clusters"] = 0
    return out


def point_differences(matched, by, chosen, holm_within=False, suffixes=paired.SIDES):
    out = point_only(matched, by, [m.minus() for m in chosen], suffixes)
    out["pairs"] = len(matched)
    for m in chosen:
        out[f"{m.name}_a"] = out[f"{m.name}_b"] = out[f"{m.name}_p"] = np.nan
        out[f"{m.name}_n"] = len(matched)
    return out


def report_once(frame, metrics, intervals: bool) -> float:
    counts = EpisodeCounts(episodes=len(frame), pairs=len(frame))
    with ExitStack() as patches, tempfile.TemporaryDirectory() as out:
        if not intervals:
            patches.enter_context(mock.patch("conflictbench.metrics.aggregate.intervals", point_only))
            patches.enter_context(mock.patch("conflictbench.metrics.aggregate.differences", point_differences))
            patches.enter_context(
                mock.patch.object(summary, "paired_marks", lambda frame, table, spec, found: unmarked(table, spec))
            )
        started = time.perf_counter()
        report_frame(frame.copy(), counts, metrics, out_dir=out, stream=io.StringIO())
        return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", type=int, default=8)
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    plugins = conflictbench.plugins(entry_points=False)
    metrics = select_metrics(plugins, None)
    frame = synthetic_frame(args.models)
    print(f"{len(frame):,} pairs ({args.models} models x 2 prompts x {len(frame) // args.models // 2:,}); "
          f"{interval_module.__name__}")  # fmt: skip
    timings = {True: [], False: []}
    for _ in range(args.repeat):
        for with_intervals in (False, True):
            timings[with_intervals].append(report_once(frame, metrics, with_intervals))
    without, with_ = min(timings[False]), min(timings[True])
    print(f"report without intervals: {without:.1f} s (best of {args.repeat})")
    print(f"report with intervals:    {with_:.1f} s (best of {args.repeat})")
    print(f"ratio: {with_ / without:.2f}x")


if __name__ == "__main__":
    main()
