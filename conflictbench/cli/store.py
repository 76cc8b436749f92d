"""``conflictbench store check DIR [--quarantine]``: read every episode file of a store whole and say what was found.

Reports, merges, prunes and the viewer already set aside a damaged file they meet (``store/check.py``); this reads
every file, every column, page checksums verified, so damage the cheaper reads would not meet yet is found too. It
changes nothing unless asked (``--quarantine``). Exit code 0 where every file reads, 1 where some are damaged.
"""

from __future__ import annotations

from collections.abc import Sequence

from conflictbench.cli.args import Parser, store_dir
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins

SUBCOMMANDS = ("check",)
#: Where a read is long enough to show its progress (as ``merge`` does).
PROGRESS_FROM = 2000


def command(argv: Sequence[str], plugins: Plugins) -> int:
    argv = list(argv)
    if argv[:1] in (["-h"], ["--help"], ["help"]):
        print("usage: conflictbench store check DIR [--quarantine]   read every episode file; say what is damaged")
        return 0
    if not argv or argv[0] not in SUBCOMMANDS:
        named = f"unknown store command {argv[0]!r}" if argv else "name a command"
        raise UserError(f"conflictbench store: {named}; valid: {', '.join(SUBCOMMANDS)}")
    parser = Parser(
        prog="conflictbench store check",
        description="Read every episode file of the store whole (every column, page checksums verified) and say "
        "what was found: one line per damaged file. Changes nothing unless --quarantine. Exit code 1 where "
        "some file is damaged.",
    )
    parser.add_argument("store", metavar="DIR", help="the run.out directory of earlier runs")
    parser.add_argument("--quarantine", action="store_true",
                        help="move each damaged file to DIR/damaged/ with a note why (never deleted); the next run "
                        "plays those episodes again")  # fmt: skip
    parser.add_argument("--no-progress", action="store_true", help="no progress display")
    args = parser.parse_args(argv[1:])
    from conflictbench.sim.progress import CountProgress
    from conflictbench.store import EpisodeStore
    from conflictbench.store.check import DAMAGED, check_files, set_aside_list

    root = store_dir(args.store)
    store = EpisodeStore(root)
    if not (store.episodes_dir.is_dir() or store.replay_dir.is_dir()):
        raise UserError(f"{root} is not an episode store (no {store.episodes_dir.name}/ folder)")
    files = store.kept_files() + store.waiting_files()
    bar = CountProgress(len(files), "store check: episode files read",
                        enabled=len(files) > PROGRESS_FROM and not args.no_progress)  # fmt: skip
    try:
        result = check_files(files, args.quarantine, on_file=bar.update)
    finally:
        bar.close()
    earlier = len(set_aside_list(root)) - sum(moved is not None for _, _, moved in result.damaged)
    aside = f"; {earlier} set aside earlier ({root / DAMAGED}/)" if earlier else ""
    if not result.damaged:
        print(f"conflictbench: {root}: {result.read} episode files read: all readable{aside}")
        return 0
    for path, why, moved in result.damaged:
        where = f": set aside as {moved.relative_to(root)}" if moved is not None else ""
        print(f"damaged: {path.relative_to(root)} ({why}){where}")
    if args.quarantine:
        kept = sum(moved is None for _, _, moved in result.damaged)
        then = "set aside; the next run plays them again" + (f" ({kept} could not be moved)" if kept else "")
    else:
        then = f"`conflictbench store check --quarantine {root}` sets them aside (the next run plays them again)"
    print(f"conflictbench: {root}: {len(result.damaged)} of {result.read} episode files damaged{aside}; {then}")
    return 1
