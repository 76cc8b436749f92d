"""``conflictbench report DIR``: tables from an episode store, playing nothing."""

from __future__ import annotations

import io
import sys
from collections.abc import Sequence
from pathlib import Path

from conflictbench.cli.args import Parser, store_dir
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench report", description="Tables from an episode store; plays nothing.")
    parser.add_argument("store", metavar="DIR", help="the run.out directory of earlier runs")
    parser.add_argument("--metrics", help="comma-separated metric names (default: all registered)")
    parser.add_argument("--out", help="where to write the table files (default: DIR/report)")
    parser.add_argument(
        "--suite",
        metavar="FILE",
        help="report this suite file's conflict episodes (default: the suite conflictbench ships; episodes of "
        "other suites or versions are counted, not shown)",
    )
    parser.add_argument("--all-suites", action="store_true", help="report the conflict episodes of every suite")
    args = parser.parse_args(argv)
    from conflictbench.report import report_store
    from conflictbench.store import EpisodeStore

    root = store_dir(args.store)
    store = EpisodeStore(root)
    if len(store) == 0:
        raise UserError(f"{root} holds no stored episodes (expected {root}/episodes/<policy>/*.parquet)")
    metrics = [m.strip() for m in args.metrics.split(",") if m.strip()] if args.metrics else None
    if args.all_suites and args.suite:
        raise UserError("--suite and --all-suites exclude each other")
    suite, cases = (None, None) if args.all_suites else _suite(args.suite)
    tables = io.StringIO()  # the files are written before anything is printed: `report DIR | head` keeps them
    report_store(store, plugins, out_dir=Path(args.out) if args.out else root / "report", metrics=metrics,
                 stream=tables, suite=suite, suite_cases=cases)  # fmt: skip
    sys.stdout.write(tables.getvalue())
    return 0


def _suite(path: str | None) -> tuple[str, frozenset[str]]:
    """``name version`` of the suite file (default: the shipped one), as its conflict episodes store it,
    and the ids of the cases it plays."""
    from conflictbench.tasks.suite.file import load_suite

    try:
        suite = load_suite(path)
        return suite.label, frozenset(c.case_id for c in suite.accepted())
    except OSError as exc:
        raise UserError(f"--suite {path}: {exc.strerror or exc}") from None
