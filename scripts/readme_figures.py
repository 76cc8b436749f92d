"""README's figures of the default run, made by a real run of it, and checked against one.

    .venv/bin/python scripts/readme_figures.py             plays `conflictbench` (the default slice) into a fresh
                                                           store and writes its tables into README.md
    .venv/bin/python scripts/readme_figures.py --check     the same run; exit 1, showing the difference, where
                                                           README's tables are not what the run reports
    .venv/bin/python scripts/readme_figures.py --store DIR a store a default run wrote (DIR/report), played no more

README holds the block between the markers below: the run's three tables as it writes them (``report/*.md``, the
numbers it prints), and how long it took. The rollouts are deterministic, so a fresh clone reports the same
numbers; the time is the machine's and is left out of the check. CI runs the check (.ci/run).

On a processor other than the one README's block names, the learned subject's actions differ in their last bits
(its network's float kernels are the processor's, as the pinned actions' note says), and the closed loop makes
those bits another path: every episode's outcome stays, its process measures do not. There the check compares the
outcome columns (the rates, dSR and FR, their intervals and counts) and says in a line that the process columns
are the recording processor's.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from readme_block import ReadmeBlock

from conflictbench.testing.observations import processor  # the name pinned actions record too

BEGIN = "<!-- scripts/readme_figures.py writes what follows, from a real default run; do not edit it by hand -->"
END = "<!-- end of scripts/readme_figures.py -->"
BLOCK = ReadmeBlock("readme_figures", BEGIN, END)
TABLES = ("table1_overall", "table2_by_family", "table3_qualified_failures")
TIME = re.compile(r", played in \d+ min \d+ s on a \d+-core machine(?: \(.*? when it started\))?")
RECORDED_ON = re.compile(r"on a \d+-core machine \((.*?), no GPU used")
#: The columns a processor's float kernels cannot change (outcomes, and what names a row).
OUTCOME_COLUMNS = {"model", "prompt", "family", "level", "tasks", "PCSR", "RGSR", "dSR", "FR"}


def play(folder: Path) -> tuple[Path, float, float]:
    """The default run (``conflictbench`` as a user types it, no bar) into ``folder/results``; its store, seconds
    and the load average when it started (other work on the machine stretches the time)."""
    load = os.getloadavg()[0]
    started = time.monotonic()
    command = [sys.executable, "-m", "conflictbench.cli", "run.progress=false"]
    done = subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=3600)
    if done.returncode != 0:
        sys.exit(f"[readme_figures] the default run exited {done.returncode}:\n{done.stderr[-3000:]}")
    return folder / "results", time.monotonic() - started, load


def block(store: Path, seconds: float | None, load: float | None = None) -> str:
    """README's block for the report of the default run in ``store``."""
    report = store / "report"
    missing = [name for name in TABLES if not (report / f"{name}.md").is_file()]
    if missing:
        sys.exit(f"[readme_figures] {report} has no {', '.join(missing)}: not a default run's store")
    episodes = len(list((store / "episodes").rglob("*.parquet")))
    took = (
        f", played in {int(seconds // 60)} min {int(seconds % 60)} s on a {os.cpu_count()}-core machine"
        + (f" ({processor()}, no GPU used, load average {load:.1f} when it started)" if load is not None else "")
        if seconds
        else ""
    )
    lines = [BEGIN, "", f"`conflictbench`, the default slice ({episodes} episodes{took}):"]
    for name in TABLES:
        lines += ["", (report / f"{name}.md").read_text().strip()]
    return "\n".join([*lines, "", END])


def outcome_columns(text: str) -> str:
    """``text`` with each Markdown table cut to :data:`OUTCOME_COLUMNS`, its cells stripped of the padding that
    the other columns' widths decide."""
    out, keep = [], None
    for line in text.splitlines():
        if not line.startswith("|"):
            out.append(line)
            keep = None
            continue
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if keep is None:  # the header
            keep = [i for i, cell in enumerate(cells) if cell.strip("*") in OUTCOME_COLUMNS]
        out.append("| " + " | ".join(cells[i] for i in keep) + " |")
    return "\n".join(out)


def comparison(readme_block: str) -> tuple[Callable[[str], str], str | None]:
    """How to compare README's block with a run here: all of it where this processor recorded it, else only the
    outcome columns (with the line that says so)."""
    recorded = RECORDED_ON.search(readme_block)
    if recorded is None or recorded.group(1) == processor():
        return (lambda text: TIME.sub("", text)), None
    note = (
        f"[readme_figures] README's figures were played on {recorded.group(1)}, this is {processor()}: "
        "the outcome columns are compared; the process columns are the recording processor's"
    )
    return (lambda text: outcome_columns(TIME.sub("", text))), note


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare with README instead of writing it")
    parser.add_argument("--store", type=Path, help="a store a default run wrote (nothing is played)")
    args = parser.parse_args()
    BLOCK.current()  # no block to put it in: said before the run
    if args.store is not None:
        new = block(args.store, None)  # how long it took is not known: the block says nothing of it
    else:
        with tempfile.TemporaryDirectory(prefix="readme-figures-") as folder:
            store, seconds, load = play(Path(folder))
            new = block(store, seconds, load)
    # the time is the machine's: the check leaves it out; another processor's process columns too
    same, note = comparison(BLOCK.current()) if args.check else ((lambda text: text), None)
    if note:
        print(note)
    return BLOCK.write_or_check(new, args.check, "default-run figures", same=same)


if __name__ == "__main__":
    sys.exit(main())
