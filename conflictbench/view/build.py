"""Building the viewer's site from an episode store: measures, videos by replay, pages, index."""

from __future__ import annotations

import os
import shlex
import time
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from itertools import islice
from pathlib import Path

import pandas as pd

from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins
from conflictbench.metrics import evaluate_pairs
from conflictbench.report.from_store import CHUNK_PAIRS, loaded_pairs, paper_beside
from conflictbench.report.summary import select_metrics
from conflictbench.store import EpisodeStore

from .episodes import episode_page, reference_episodes, references_section
from .pairs import Selection, choose
from .site import index_page, pair_page, paper_section
from .videos import current_meta, playable, render_videos, write_atomic


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
    """The site's folder exists and takes files, or the user hears why not in one line."""
    if out.exists() and not out.is_dir():
        raise UserError(f"cannot write the site to {out}: it is a file, not a folder")
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
    ``command`` (the one that built the site) with ``--pair``."""
    from conflictbench.tasks.suite.file import load_suite

    started = time.perf_counter()
    store = EpisodeStore(store_dir)
    cases = {case.case_id: case for case in load_suite(suite_file).cases}
    pairs, rows = choose(store, selection, allow_none=True)
    references = reference_episodes(store, selection)
    if not pairs and not references:
        raise UserError(f"{store.root} holds no pairs and no reference episodes to show")
    names = [p.conflict.episode_id for p in pairs]
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
    rendered, failed, render_s = render_videos(store, out, [(r.episode_id, r.policy) for r in by_task], workers,
                                               progress)  # fmt: skip

    rerun = list(command or ["conflictbench", "view", str(store_dir), "--out", str(out)])
    metrics = select_metrics(plugins, None)
    measure_names = [m.name for m in metrics]
    with_both: set[str] = set()
    index_rows: list[dict] = []
    frames = []
    loaded = loaded_pairs(store, pairs)  # each pair's arrays read once: measured, then its page written
    while chunk := list(islice(loaded, CHUNK_PAIRS)):
        frame = evaluate_pairs([r for r, _ in chunk], [c for _, c in chunk], plugins=plugins, metrics=measure_names)
        frames.append(frame)
        for (reference, conflict), measured in zip(chunk, frame[measure_names].to_dict("records"), strict=True):
            i = len(index_rows)
            row = {**rows.iloc[i].to_dict(), **measured}
            index_rows.append(row)
            metas = {r.episode_id: meta for r in (reference, conflict) if (meta := current_meta(out, r))}
            if all(playable(metas.get(r.episode_id)) for r in (reference, conflict)):
                with_both.add(conflict.episode_id)
            neighbours = (names[i - 1] if i else None, names[i + 1] if i + 1 < len(names) else None)
            hint = "Render it with: " + shlex.join([*rerun, "--pair", conflict.episode_id])
            page = pair_page(row, reference, conflict, cases.get(conflict.case_id or ""), metrics, metas,
                             neighbours, hint)  # fmt: skip
            write_atomic(out / "pairs" / f"{conflict.episode_id}.html", page)
    shown_references = set()
    hint = "Render it with: " + shlex.join([*rerun, "--videos", "all"])
    for start in range(0, len(references), CHUNK_PAIRS):  # arrays (what a video's note is checked against) by chunk
        part = references[start : start + CHUNK_PAIRS]
        loaded_refs = {r.episode_id: r for r in store.load([(r.episode_id, r.policy) for _, r in part])}
        for label, light in part:
            record = loaded_refs[light.episode_id]
            meta = current_meta(out, record)
            write_atomic(out / "episodes" / f"{record.episode_id}.html", episode_page(label, record, meta, hint))
            if playable(meta):
                shown_references.add(record.episode_id)
    for stale in (out / "episodes").glob("*.html"):
        if stale.stem not in {r.episode_id for _, r in references}:
            stale.unlink(missing_ok=True)
    shown = set(names)
    for stale in (out / "pairs").glob("*.html"):  # pages of pairs this build does not show (filters, a new store)
        if stale.stem not in shown:
            stale.unlink(missing_ok=True)
    beside = (
        paper_section(pd.concat(frames, ignore_index=True), metrics, paper_beside(store, plugins)) if frames else ""
    )
    listed = references_section(references, shown_references)
    write_atomic(out / "index.html", index_page(index_rows, metrics, str(store_dir), with_both, beside, listed))
    for name in ("viewer.js", "viewer.css"):
        write_atomic(out / "assets" / name, (resources.files("conflictbench.view") / "assets" / name).read_bytes())
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    return Built(len(pairs), len(references), rendered, failed, time.perf_counter() - started, render_s, size, out)
