"""``conflictbench compare DIR A B``: paired differences between two models, settings or prompt conditions."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from conflictbench.cli.args import Parser, store_dir
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins

EPILOG = """examples:
  conflictbench compare results pi0 pi05                  two models of one store
  conflictbench compare results subject@p0 subject@p1     P0 against P1 of one model
  conflictbench compare results "random seed=1" "random seed=2"   two settings of one policy
  conflictbench compare results pi0 pi0 --against other/  the same model in two stores (two checkpoints)
"""


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(
        prog="conflictbench compare",
        description="Paired differences between two sides: each measure's difference over the pairs both played, "
        "with its 95 % interval (clustered by base task) and a verdict, overall, per family and per level.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("store", metavar="DIR", help="the episode store (run.out) holding side A (and B)")
    parser.add_argument("a", metavar="A", help="a model as the report names it, optionally @p0 or @p1")
    parser.add_argument("b", metavar="B", help="the other side, in the same form")
    parser.add_argument("--against", metavar="DIR2", help="read side B from this store instead")
    parser.add_argument("--metrics", help="comma-separated metric names (default: all registered)")
    parser.add_argument("--csv", metavar="FILE", help="also write the rows as CSV")
    parser.add_argument("--suite", metavar="FILE", help="compare this suite file's conflict episodes (as report)")
    parser.add_argument("--all-suites", action="store_true", help="compare the conflict episodes of every suite")
    args = parser.parse_args(argv)

    from conflictbench.cli.report import _suite
    from conflictbench.report.compare import check_side, compare, csv_frame, parse_side, render
    from conflictbench.report.from_store import store_frame
    from conflictbench.report.summary import select_metrics
    from conflictbench.store import EpisodeStore

    if args.all_suites and args.suite:
        raise UserError("--suite and --all-suites exclude each other")
    roots = [store_dir(args.store), store_dir(args.against) if args.against else None]
    stores = [EpisodeStore(root) if root else None for root in roots]
    for root, store in zip(roots, stores):
        if store is not None and len(store) == 0:
            raise UserError(f"{root} holds no stored episodes (expected {root}/episodes/<policy>/*.parquet)")
    a = parse_side(args.a, str(roots[0]))
    b = parse_side(args.b, str(roots[1] or roots[0]))
    if a == b:
        raise UserError(f"A and B are both {a.text} of {a.store}: name two models, two prompts (@p0, @p1) or --against")
    metrics = select_metrics(
        plugins, [m.strip() for m in args.metrics.split(",") if m.strip()] if args.metrics else None
    )
    suite, cases = (None, None) if args.all_suites else _suite(args.suite)
    options = {"suite": suite, "suite_cases": cases}
    if stores[1] is None:
        frame, models = store_frame(stores[0], plugins, metrics, models={a.model, b.model}, **options)
        frames = (frame, frame)
        labels = (models, models)
    else:
        fa, ma = store_frame(stores[0], plugins, metrics, models={a.model}, **options)
        fb, mb = store_frame(stores[1], plugins, metrics, models={b.model}, **options)
        frames, labels = (fa, fb), (ma, mb)
    for side, frame, models in zip((a, b), frames, labels):
        check_side(side, models, sorted(set(frame.loc[frame["model"] == side.model, "prompt"])))
    result = compare(frames[0], frames[1], a, b, metrics)
    print(render(result))
    if args.csv:
        path = Path(args.csv)
        path.parent.mkdir(parents=True, exist_ok=True)
        csv_frame(result).to_csv(path, index=False, na_rep="n/a")
        print(f"written to {path}")
    return 0
