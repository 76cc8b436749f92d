"""README's figures of the default run, made by a real run of it, and checked against one.

    .venv/bin/python scripts/readme_figures.py             plays `conflictbench` (the default slice) into a fresh
                                                           store and writes its tables into README.md
    .venv/bin/python scripts/readme_figures.py --check     the same run; exit 1, showing the difference, where
                                                           README's tables are not what the run reports
    .venv/bin/python scripts/readme_figures.py --store DIR a store a default run wrote (DIR/report), played no more

README holds the block between the markers below: the run's three tables as it writes them (``report/*.md``, the
numbers it prints), and how long it took. The rollouts are deterministic, so a fresh clone reports the same
numbers; the time is the machine's and is left out of the check. CI runs the check (.ci/run).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from readme_block import ReadmeBlock

from conflictbench.testing.observations import processor  # the name pinned actions record too

BEGIN = "<!-- scripts/readme_figures.py writes what follows, from a real default run; do not edit it by hand -->"
END = "<!-- end of scripts/readme_figures.py -->"
BLOCK = ReadmeBlock("readme_figures", BEGIN, END)
TABLES = ("table1_overall", "table2_by_family", "table3_qualified_failures")
TIME = re.compile(r", played in \d+ min \d+ s on a \d+-core machine(?: \(.*? when it started\))?")


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
    # the time is the machine's: the check leaves it out
    return BLOCK.write_or_check(new, args.check, "default-run figures", same=lambda text: TIME.sub("", text))


if __name__ == "__main__":
    sys.exit(main())
