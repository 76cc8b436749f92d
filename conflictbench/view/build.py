"""Building the viewer's site from an episode store: measures, videos by replay, pages, index.

Videos are kept between builds (one per episode, with a JSON note of its replay): a second build renders only
what is new, and an interrupted build keeps every video it finished.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from conflictbench.core import EpisodeRecord
from conflictbench.core.plugins import Plugins
from conflictbench.report.from_store import loaded_pairs
from conflictbench.sim.progress import RunProgress, duration
from conflictbench.store import EpisodeStore

from .pairs import Selection, choose, measures
from .site import index_page, pair_page
from .video import FPS, Mp4Sink

FRAME_EVERY = 2  # 10 frames per second of a 20 Hz rollout, played in real time: half the renders


@dataclass
class Built:
    pairs: int
    rendered: int
    failed: int
    seconds: float
    render_seconds: float
    bytes: int
    out: Path


class ReplayProgress(RunProgress):
    def line(self) -> str:
        left = self.remaining_s()
        return " | ".join(
            [
                f"videos: {self.done}/{self.total} episodes replayed",
                f"{self.counts['errors']} failed",
                f"about {duration(left)} left" if left is not None else "time left: after the first one",
                f"{duration(time.monotonic() - self.started)} so far",
            ]
        )


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(text, encoding="utf-8")
    os.replace(temporary, path)


def video_meta(out: Path, episode_id: str) -> dict[str, Any] | None:
    try:
        return json.loads((out / "videos" / f"{episode_id}.json").read_text())
    except (OSError, ValueError):
        return None


def episode_digest(record: EpisodeRecord) -> str:
    """What a video shows of an episode: its actions and stored path (an episode played again under the same id,
    after an infrastructure failure, has other ones)."""
    digest = hashlib.sha256(np.ascontiguousarray(record.actions, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(record.eef_pos, dtype=np.float64).tobytes())
    return digest.hexdigest()[:20]


def _current(meta: dict[str, Any] | None, out: Path, record: EpisodeRecord) -> bool:
    """A video from an earlier build that still fits: the same episode, frame rate, no error, the file there."""
    return bool(
        meta
        and not meta.get("error")
        and meta.get("episode") == episode_digest(record)
        and meta.get("frame_every") == FRAME_EVERY
        and (out / "videos" / f"{record.episode_id}.mp4").is_file()
    )


def render_videos(store: EpisodeStore, out: Path, episodes: list[tuple[str, str]], workers: int,
                  progress: bool) -> tuple[int, int, float]:  # fmt: skip
    """Replay the (episode id, policy) given that lack a current video; returns (rendered, failed, seconds)."""
    from conflictbench.core.policy import DEFAULT_WARMUP_STEPS
    from conflictbench.sim.replay import ReplayJob, replay_all

    records = store.load(episodes)
    todo = [r for r in records if not _current(video_meta(out, r.episode_id), out, r)]
    jobs = [
        ReplayJob(
            episode_id=r.episode_id,
            suite=r.suite,
            task_id=r.task_id,
            init_state=r.init_state,
            seed=r.seed,
            warmup_steps=DEFAULT_WARMUP_STEPS if r.warmup_steps is None else r.warmup_steps,
            actions=r.actions,
            eef_pos=r.eef_pos,
            sink=Mp4Sink(str(out / "videos" / f"{r.episode_id}.mp4"), fps=FPS // FRAME_EVERY),
            frame_every=FRAME_EVERY,
        )
        for r in todo
    ]
    assumed = {r.episode_id for r in todo if r.warmup_steps is None}
    digests = {r.episode_id: episode_digest(r) for r in todo}
    bar = ReplayProgress(len(jobs), "videos", enabled=progress)
    rendered = failed = 0
    started = time.perf_counter()
    try:
        for result in replay_all(jobs, workers=workers):
            meta = {
                "episode": digests[result.episode_id],
                "steps": result.steps if result.error is None else None,
                "frame_every": FRAME_EVERY,
                "deviation_m": result.deviation_m,
                "warmup_assumed": result.episode_id in assumed,  # a store written before the column
                "seconds": round(result.seconds, 2),
                "bytes": result.bytes,
                "error": result.error,
            }
            _write_atomic(out / "videos" / f"{result.episode_id}.json", json.dumps(meta))
            rendered += result.error is None
            failed += result.error is not None
            bar.set_postfix(errors=failed)
            bar.update()
    finally:
        bar.close()
    return rendered, failed, time.perf_counter() - started


def build_site(
    store_dir: Path,
    out: Path,
    plugins: Plugins,
    selection: Selection,
    *,
    videos: int | None = 30,
    workers: int = 2,
    suite_file: str | None = None,
    progress: bool = True,
) -> Built:
    """Write the site for the pairs chosen; ``videos`` pairs (the first ones; None: all) get videos."""
    from conflictbench.tasks.suite.file import load_suite

    started = time.perf_counter()
    store = EpisodeStore(store_dir)
    cases = {case.case_id: case for case in load_suite(suite_file).cases}
    pairs, rows = choose(store, selection)
    frame, metrics = measures(store, pairs, plugins)
    rows = rows.join(frame[[m.name for m in metrics]])
    rows["instruction"] = [p.conflict.instruction for p in pairs]
    with_video = pairs if videos is None else pairs[:videos]
    wanted = {r.episode_id: r.policy for p in with_video for r in (p.reference, p.conflict)}
    rendered, failed, render_s = render_videos(store, out, sorted(wanted.items()), workers, progress)

    metas = {eid: video_meta(out, eid) for eid in wanted}
    metas = {eid: meta for eid, meta in metas.items() if meta}
    names = [p.conflict.episode_id for p in pairs]
    hint = f"Render it with: conflictbench view {store_dir} --pair ID --out {out}"
    for i, (reference, conflict) in enumerate(loaded_pairs(store, pairs)):
        neighbours = (names[i - 1] if i else None, names[i + 1] if i + 1 < len(names) else None)
        page = pair_page(rows.iloc[i].to_dict(), reference, conflict, cases.get(conflict.case_id or ""), metrics,
                         metas, neighbours, hint.replace("ID", conflict.episode_id))  # fmt: skip
        _write_atomic(out / "pairs" / f"{conflict.episode_id}.html", page)
    with_both = {n for p, n in zip(pairs, names, strict=True) if {p.reference.episode_id, n} <= set(metas)}
    _write_atomic(out / "index.html", index_page(rows.to_dict("records"), metrics, str(store_dir), with_both))
    assets = out / "assets"
    assets.mkdir(parents=True, exist_ok=True)
    for name in ("viewer.js", "viewer.css"):
        with resources.as_file(resources.files("conflictbench.view") / "assets" / name) as source:
            shutil.copyfile(source, assets / name)
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    return Built(len(pairs), rendered, failed, time.perf_counter() - started, render_s, size, out)
