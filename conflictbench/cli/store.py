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
    from conflictbench.store.paths import is_store

    root = store_dir(args.store)
    store = EpisodeStore(root)
    if not is_store(root):
        raise UserError(f"{root} is not an episode store (no {store.episodes_dir.name}/ folder)")
    files = store.kept_files() + store.waiting_files()
    bar = CountProgress(len(files), "store check: episode files read",
                        enabled=len(files) > PROGRESS_FROM and not args.no_progress)  # fmt: skip
    try:
        result = check_files(files, args.quarantine, on_file=bar.update)
    finally:
        bar.close()
    # A linked episodes/ or replay/ is not read (a store is read without following links): say so, never "all
    # readable" over files nobody looked at (#42).
    linked = [d.name for d in (store.episodes_dir, store.replay_dir) if d.is_symlink()]
    _say(root, result, args.quarantine, len(set_aside_list(root)), root / DAMAGED, bool(linked))
    for name in linked:
        print(f"conflictbench: {root / name} is a link: a store is read without following links, so nothing under "
              "it was checked (copy the files into the store, or `conflictbench merge` them)")  # fmt: skip
    return 1 if result.damaged or result.other_version or linked else 0


def _say(root, result, quarantine: bool, aside_now: int, damaged_dir, linked: bool) -> None:
    earlier = aside_now - sum(moved is not None for _, _, moved, _ in result.damaged)
    aside = f"; {earlier} set aside earlier ({damaged_dir}/)" if earlier else ""
    for path, why in result.other_version:
        print(f"not readable by this version: {path.relative_to(root)} ({why}): likely written by another (newer) "
              "conflictbench version; left in place")  # fmt: skip
    for path, why, moved, why_not in result.damaged:
        where = f": set aside as {moved.relative_to(root)}" if moved is not None else ""
        where += f": could not be moved ({why_not})" if why_not is not None else ""
        print(f"damaged: {path.relative_to(root)} ({why}){where}")
    other = f"; {len(result.other_version)} not readable by this version" if result.other_version else ""
    if not result.damaged:
        readable = "no damage" if result.other_version or linked else "all readable"
        print(f"conflictbench: {root}: {result.read} episode files read: {readable}{other}{aside}")
        return
    if quarantine:
        kept = [why_not for *_, why_not in result.damaged if why_not is not None]
        then = "set aside; the next run plays them again"
        then += f" ({len(kept)} could not be moved: {kept[0]})" if kept else ""
    else:
        then = f"`conflictbench store check --quarantine {root}` sets them aside (the next run plays them again)"
    print(f"conflictbench: {root}: {len(result.damaged)} of {result.read} episode files damaged{other}{aside}; {then}")
