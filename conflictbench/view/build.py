"""Building the viewer's site from an episode store: the plan said at once, pages and index first, then videos by
replay, then the pages again with the videos that landed."""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins
from conflictbench.core.words import counted
from conflictbench.sim.progress import duration
from conflictbench.store import EpisodeStore
from conflictbench.store.check import going_on
from conflictbench.store.paths import check_name

from .episodes import reference_episodes
from .pages import Site
from .pairs import Selection, choose
from .videos import FOLDERS, FRAME_EVERY, lacking_videos, render_videos

#: A replay's cost per rendered frame on a CPU (software rendering, the simulation between frames included) where
#: the site has no replays of its own to go by: README's viewer figures, 81 ms a replayed step with a frame every
#: second step, on 2 cores.
SECONDS_PER_FRAME = 0.16


def seconds_per_frame(out: Path) -> float | None:
    """What a frame cost this site's earlier replays, from their notes (``videos/<episode>.json``); None without."""
    seconds = frames = 0
    for note in (out / "videos").glob("*.json"):
        try:
            meta = json.loads(note.read_text())
        except (OSError, ValueError):
            continue
        if meta.get("error") is None and meta.get("steps") and meta.get("seconds"):
            seconds += meta["seconds"]
            frames += meta["steps"] // meta.get("frame_every", FRAME_EVERY)
    return seconds / frames if frames else None


def replay_estimate(steps: Sequence[int], workers: int, per_frame: float = SECONDS_PER_FRAME) -> float:
    """Seconds to replay episodes of these step counts, ``workers`` at a time, at ``per_frame`` seconds a frame."""
    if not steps:
        return 0.0
    frames = sum(n // FRAME_EVERY for n in steps)
    return frames * per_frame / max(1, min(workers, len(steps)))


def plan_line(pairs: int, references: int, steps: Sequence[int], workers: int, out: Path) -> str:
    """What a build is about to do, said before it starts: the pages, the replays and their time (at what a frame
    cost this site's earlier replays, else on an idle CPU as measured for README)."""
    text = (
        f"conflictbench view: {counted(pairs, 'pair')}, {counted(references, 'reference episode page')}, "
        f"{counted(len(steps), 'episode')} to replay for videos"
    )
    index = (out / "index.html").resolve().as_uri()
    if not steps:
        return text + f"; the pages come next: {index}"
    measured = seconds_per_frame(out)
    basis = "on an idle CPU" if measured is None else f"at the {measured:.2f} s a frame of this site's earlier replays"
    estimate = duration(replay_estimate(steps, workers, SECONDS_PER_FRAME if measured is None else measured))
    return (
        f"{text} (about {estimate} with {workers} worker(s) {basis}, longer under load); the pages come "
        f"first: open {index} now and reload it as videos land"
    )


@dataclass
class Built:
    pairs: int
    episodes: int  # reference episodes' own pages
    rendered: int
    failed: int
    seconds: float
    render_seconds: float
    bytes: int
    out: Path


def prepare_out(out: Path) -> None:
    """The site's folder exists and takes files, or the user hears why not in one line. Its own folders are never
    links: the viewer writes pages there and deletes stale ones, which a link would take to another folder (#42)."""
    if out.exists() and not out.is_dir():
        raise UserError(f"cannot write the site to {out}: it is a file, not a folder")
    for name in FOLDERS:
        if (out / name).is_symlink():
            raise UserError(f"cannot write the site to {out}: {out / name} is a link (the viewer writes and deletes "
                            "only in folders of its own; remove the link)")  # fmt: skip
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".conflictbench-probe.{os.getpid()}.tmp"
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise UserError(f"cannot write the site to {out}: {exc.strerror or exc}") from None


def build_site(
    store_dir: Path,
    out: Path,
    plugins: Plugins,
    selection: Selection,
    *,
    videos: int | None = 30,
    video_pairs: frozenset[str] | set[str] = frozenset(),
    workers: int = 2,
    suite_file: str | None = None,
    progress: bool = True,
    command: Sequence[str] | None = None,
) -> Built:
    """Write the site for the pairs chosen. Videos go to the first ``videos`` pairs in the index's order (None:
    all) and to the pairs named in ``video_pairs`` (conflict episode ids); a page without one says to run
    ``command`` (the one that built the site) with ``--pair``. An episode met damaged by its arrays is set aside,
    named in one line, and the site built again without it (``check.going_on``)."""
    from conflictbench.tasks.suite.file import load_suite

    started = time.perf_counter()
    store = EpisodeStore(store_dir)
    cases = {case.case_id: case for case in load_suite(suite_file).cases}
    options = dict(videos=videos, video_pairs=video_pairs, workers=workers, progress=progress, command=command)
    return going_on(lambda: _build(store, store_dir, out, plugins, selection, cases, started, **options))


def _build(
    store: EpisodeStore,
    store_dir: Path,
    out: Path,
    plugins: Plugins,
    selection: Selection,
    cases: dict,
    started: float,
    *,
    videos: int | None,
    video_pairs: frozenset[str] | set[str],
    workers: int,
    progress: bool,
    command: Sequence[str] | None,
) -> Built:
    pairs, rows = choose(store, selection, allow_none=True)
    references = reference_episodes(store, selection)
    if not pairs and not references:
        raise UserError(f"{store.root} holds no pairs and no reference episodes to show")
    names = [p.conflict.episode_id for p in pairs]
    for episode_id in sorted({r.episode_id for p in pairs for r in (p.reference, p.conflict)}
                             | {r.episode_id for _, r in references}):  # fmt: skip
        check_name("episode id", episode_id, f"{store.root}: ")  # each names files of the site: checked before any
    if unknown := set(video_pairs) - set(names):
        raise UserError(f"--pair {', '.join(sorted(unknown))}: not among the pairs this command shows")
    prepare_out(out)
    rows["instruction"] = [p.conflict.instruction for p in pairs]

    with_video = [p for i, p in enumerate(pairs) if (videos is None or i < videos) or names[i] in video_pairs]
    wanted = {r.episode_id: r for p in with_video for r in (p.reference, p.conflict)}
    budget = None if videos is None else max(0, videos - len(with_video))  # the pairs' first, then references'
    alone = [r for _, r in references if r.episode_id not in wanted]
    wanted.update({r.episode_id: r for r in (alone if budget is None else alone[:budget])})
    by_task = sorted(wanted.values(), key=lambda r: (r.suite, r.task_id, r.episode_id))  # an env per task, once
    todo = lacking_videos(store, out, [(r.episode_id, r.policy) for r in by_task])
    print(plan_line(len(pairs), len(references), [steps for _, _, steps in todo], workers, out), file=sys.stderr)

    rerun = list(command or ["conflictbench", "view", str(store_dir), "--out", str(out)])
    site = Site(store, out, plugins, pairs, rows, references, cases, rerun, str(store_dir))
    site.write()  # first: the pages are of use while the videos render
    rendered = failed = 0
    render_s = 0.0
    if todo:
        rendered, failed, render_s = render_videos(store, out, [(i, p) for i, p, _ in todo], workers, progress)
        site.write()  # again, now with the videos that landed
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    return Built(len(pairs), len(references), rendered, failed, time.perf_counter() - started, render_s, size, out)
