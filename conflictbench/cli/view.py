"""``conflictbench view DIR``: a static HTML site of the paired episodes in a store, videos included."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from conflictbench.cli.args import Parser, store_dir
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins


def _names(values: list[str] | None) -> set[str]:
    return {v.strip() for value in values or () for v in value.split(",") if v.strip()}


def _videos(text: str) -> int | None:
    if text == "all":
        return None
    if text.isdigit():
        return int(text)
    raise UserError(f"--videos takes a number of pairs or 'all', not {text!r}")


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(
        prog="conflictbench view",
        description="A static HTML site of the paired episodes in an episode store: one page per pair (both "
        "rollouts as videos, paths, distances, actions, measures, the case), an index with filters. Videos "
        "are rendered by replaying the stored actions with a camera on. Opens from disk: DIR/view/index.html.",
    )
    parser.add_argument("store", metavar="DIR", help="the run.out directory of earlier runs")
    parser.add_argument("--out", help="where to write the site (default: DIR/view)")
    for name in ("model", "family", "level", "prompt", "outcome"):
        parser.add_argument(f"--{name}", action="append", metavar="NAMES", help=f"only these {name}s (comma-separated)")
    parser.add_argument("--pair", action="append", metavar="ID",
                        help="also render videos for these pairs (conflict episode ids: a page's name)")  # fmt: skip
    parser.add_argument("--videos", default="30", metavar="N",
                        help="render videos for the first N pairs shown, or 'all' (default: 30)")  # fmt: skip
    parser.add_argument("--workers", type=int, default=2, help="replay processes (default: 2)")
    parser.add_argument("--suite", metavar="FILE", help="the suite file the cases came from (default: the shipped one)")
    parser.add_argument("--no-progress", action="store_true", help="no progress display")
    args = parser.parse_args(argv)
    from conflictbench.view import Selection, build_site

    root = store_dir(args.store)
    if args.workers < 1:
        raise UserError("--workers must be at least 1")
    if args.suite and not Path(args.suite).is_file():
        raise UserError(f"no such suite file: {args.suite}")
    selection = Selection(**{name: _names(getattr(args, name)) for name in ("model", "family", "level", "prompt",
                                                                             "outcome")})  # fmt: skip
    out = Path(args.out) if args.out else root / "view"
    if not args.out and out.is_symlink():  # --out is the user's choice; a link inside a store is the store's data
        raise UserError(f"{out} is a link: the site is written in the store's own view/ folder only (or give --out)")
    pages = {name.removesuffix(".html") for name in _names(args.pair)}  # an id, or its page's file name
    try:
        built = build_site(root, out, plugins, selection, videos=_videos(args.videos), video_pairs=pages,
                           workers=args.workers, suite_file=args.suite, progress=not args.no_progress,
                           command=["conflictbench", "view", *argv])  # fmt: skip
    except KeyboardInterrupt:
        print("\nconflictbench: interrupted; the pages are written, every finished video is kept, and the same "
              "command goes on from them",
              file=sys.stderr)  # fmt: skip
        return 130
    failed = f", {built.failed} failed (see their pages)" if built.failed else ""
    print(
        f"conflictbench: {built.pairs} pair page{'s' * (built.pairs != 1)}, {built.episodes} reference episode "
        f"page{'s' * (built.episodes != 1)}, {built.rendered} video"
        f"{'s' * (built.rendered != 1)} rendered{failed} in "
        f"{built.seconds:.0f} s; {built.bytes / 1e6:.1f} MB in {built.out}/\n"
        f"open {(built.out / 'index.html').resolve().as_uri()}",
        file=sys.stdout,
    )
    return 0
