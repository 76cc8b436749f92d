"""The non-Hydra verbs: ``conflictbench list`` and ``conflictbench report DIR``."""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
from typing import Sequence

from conflictbench.core import FAMILIES, LEVELS, PROMPT_CONDITIONS, UserError
from conflictbench.core.plugins import Plugins


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # a usage mistake is a UserError: one line, exit code 2
        raise UserError(f"{self.prog}: {message}")


def list_command(argv: Sequence[str], plugins: Plugins) -> int:
    _Parser(prog="conflictbench list", description="What can be chosen, and where it comes from.").parse_args(argv)
    from conflictbench.cli import group_choices
    from conflictbench.tasks.suite_file import load_suite

    print("policies (model=...):")
    for name, spec in sorted(plugins.policies().items()):
        print(f"  {name:<20} {spec.plugin} {spec.plugin_version}")
    print("metrics (per pair):")
    metrics = plugins.metrics()
    if not metrics:
        print("  (none registered)")
    for name, spec in sorted(metrics.items()):
        print(f"  {name:<20} {spec.plugin} {spec.plugin_version}  {spec.description}")
    suite = load_suite()
    counts = Counter((c.family, c.level) for c in suite.accepted())
    print(f"conflict families (suite=...), cases per level in {suite.name} {suite.version}:")
    for family in FAMILIES:
        per_level = "  ".join(f"{level}:{counts[(family, level)]}" for level in LEVELS)
        print(f"  {family:<20} {per_level}")
    print(f"levels (level=...): {', '.join(group_choices('level', plugins))}")
    print(f"prompt conditions (prompt=...): {', '.join(group_choices('prompt', plugins))} "
          f"(conditions: {', '.join(PROMPT_CONDITIONS)})")
    print(f"run presets (run=...): {', '.join(group_choices('run', plugins))}")
    if plugins.load_failures:
        print("plugins that failed to load:")
        for name, why in plugins.load_failures.items():
            print(f"  {name}: {why}")
    return 0


def report_command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = _Parser(prog="conflictbench report", description="Tables from an episode store; plays nothing.")
    parser.add_argument("store", metavar="DIR", help="the run.out directory of earlier runs")
    parser.add_argument("--metrics", help="comma-separated metric names (default: all registered)")
    parser.add_argument("--out", help="where to write the table files (default: DIR/report)")
    args = parser.parse_args(argv)
    from conflictbench.report import report_store
    from conflictbench.store import EpisodeStore

    root = Path(args.store)
    if not root.is_dir():
        raise UserError(f"no such directory: {root}")
    store = EpisodeStore(root)
    if len(store) == 0:
        raise UserError(f"{root} holds no stored episodes (expected {root}/episodes/<policy>/*.parquet)")
    metrics = [m.strip() for m in args.metrics.split(",") if m.strip()] if args.metrics else None
    report_store(store, plugins, out_dir=Path(args.out) if args.out else root / "report", metrics=metrics)
    return 0
