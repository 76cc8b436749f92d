"""``conflictbench merge OUT SHARD...``: one store from stores written on machines without shared storage."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from conflictbench.cli.args import Parser
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(
        prog="conflictbench merge",
        description="Copy the episodes of SHARD stores into the store OUT (made if missing): an episode already "
        "there is dropped as a duplicate (counted); one played with other code or simulator versions in another "
        "store stops the merge before anything is written. The shards are only read.",
    )
    parser.add_argument("out", metavar="OUT", help="the store to merge into (a run.out directory)")
    parser.add_argument("shards", metavar="SHARD", nargs="+", help="stores to merge from")
    parser.add_argument("--dry-run", action="store_true", help="say what would be merged, write nothing")
    args = parser.parse_args(argv)
    from conflictbench.sim.progress import CountProgress
    from conflictbench.store import EpisodeStore
    from conflictbench.store.merge import merge_stores

    for shard in args.shards:
        if not Path(shard).is_dir():
            raise UserError(f"no such directory: {shard}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out} is a file, not a store directory")
    shards = [EpisodeStore(s) for s in args.shards]
    total = sum(len(s.kept_files()) for s in (EpisodeStore(out), *shards))
    bar = CountProgress(total, "merge: episode files read", enabled=total > 2000)  # where a long read is
    try:
        plan = merge_stores(EpisodeStore(out), shards, dry_run=args.dry_run, on_file=bar.update)
    finally:
        bar.close()
    verb = "would copy" if args.dry_run else "copied"
    lines = [f"conflictbench: {verb} {len(plan.new)} episode(s) into {out}; dropped {plan.duplicates} duplicate(s)"]
    if plan.differing:
        first, other = plan.differing[0]
        lines.append(
            f"  {len(plan.differing)} duplicate(s) with another rollout than the copy kept (the policy is not "
            f"deterministic across machines?), e.g. {first.episode_id}: kept {first.path}, dropped {other.path}"
        )
    if plan.left_out_replays:
        lines.append(f"  {plan.left_out_replays} episode(s) the serving infrastructure ended were left out "
                     "(the next run plays them again)")  # fmt: skip
    print("\n".join(lines), file=sys.stdout)
    return 0
