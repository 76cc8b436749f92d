"""``conflictbench prune DIR [--delete]``: the episodes played again under a newer identity, listed or removed."""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Sequence

from conflictbench.cli.args import Parser, store_dir
from conflictbench.core.plugins import Plugins
from conflictbench.core.words import counted


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(
        prog="conflictbench prune",
        description="List the store's superseded episodes: an episode (same policy, settings, checkpoint, task, "
        "initial state, prompt, case) stored again under a newer identity (other code, simulator, model stack or "
        "budget) supersedes the older ones, which no run or report of today's code reads. Lists them; --delete "
        "removes them.",
    )
    parser.add_argument("store", metavar="DIR", help="the run.out directory of earlier runs")
    parser.add_argument("--delete", action="store_true", help="remove the superseded episodes' files")
    args = parser.parse_args(argv)
    from conflictbench.store import EpisodeStore
    from conflictbench.store.prune import remove, superseded

    root = store_dir(args.store)
    store = EpisodeStore(root)
    old = superseded(store)
    total = len(store)
    size = sum(s.bytes for s in old) / 1e6
    by_policy = ", ".join(f"{policy} {n}" for policy, n in sorted(Counter(s.policy for s in old).items()))
    if not old:
        print(f"conflictbench: none of the {counted(total, 'episode')} in {root} is superseded", file=sys.stderr)
        return 0
    for item in old:
        print(item.path)
    if not args.delete:
        print(f"conflictbench: {len(old)} of {counted(total, 'episode')} superseded (--delete removes them): "
              f"{by_policy}; {size:.1f} MB", file=sys.stderr)  # fmt: skip
        return 0
    removed = remove(store, old)  # said once done, with what it removed (a file gone meanwhile is not counted)
    gone = f" ({len(old) - removed} gone meanwhile)" if removed < len(old) else ""
    print(f"conflictbench: removed {removed} of {counted(total, 'episode')}, superseded{gone}: {by_policy}; "
          f"{size:.1f} MB", file=sys.stderr)  # fmt: skip
    return 0
