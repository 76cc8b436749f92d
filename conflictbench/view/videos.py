"""The viewer's videos: one per episode, made by replay, kept between builds with a note of what each shows.

``videos/<episode>.mp4`` and ``videos/<episode>.json`` (the episode's digest, the replay's deviation from the
stored path, its cost). A video is current while its note names the episode as stored now; a second build
renders only what is new or changed, and an interrupted one keeps every video whose note was written.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from conflictbench.core import EpisodeRecord
from conflictbench.sim.progress import CountProgress
from conflictbench.store import EpisodeStore, paths
from conflictbench.store.episodes import pid_alive

from .video import FPS, Mp4Sink

FRAME_EVERY = 2  # 10 frames per second of a 20 Hz rollout, played in real time: half the renders
LOAD_CHUNK = 64  # episodes whose arrays are in memory at once


#: The site's folders: made by the viewer, never links (a link would take its writes and deletes elsewhere, #42).
FOLDERS = ("pairs", "episodes", "videos", "assets")


def write_atomic(out: Path, path: Path, data: str | bytes) -> None:
    """``path`` in the site ``out``, whole or absent, never written through a link (:func:`paths.write_inside`)."""
    paths.write_inside(out, path, data.encode("utf-8") if isinstance(data, str) else data, "the site")


def site_file(out: Path, folder: str, episode_id: str, suffix: str) -> Path:
    """``out/<folder>/<episode id><suffix>``: an id read from a store names a file only if it is one plain name."""
    return out / folder / f"{paths.check_name('episode id', episode_id)}{suffix}"


def episode_digest(record: EpisodeRecord) -> str:
    """What a video shows of an episode: its actions and stored path (an episode played again under the same id,
    after an infrastructure failure, has other ones)."""
    digest = hashlib.sha256(np.ascontiguousarray(record.actions, dtype=np.float64).tobytes())
    digest.update(np.ascontiguousarray(record.eef_pos, dtype=np.float64).tobytes())
    return digest.hexdigest()[:20]


def video_meta(out: Path, episode_id: str) -> dict[str, Any] | None:
    try:
        return json.loads(site_file(out, "videos", episode_id, ".json").read_text())
    except (OSError, ValueError):
        return None


def current_meta(out: Path, record: EpisodeRecord) -> dict[str, Any] | None:
    """The note of a video that shows ``record`` as stored now (failed replays included), else None."""
    meta = video_meta(out, record.episode_id)
    if not meta or meta.get("episode") != episode_digest(record) or meta.get("frame_every") != FRAME_EVERY:
        return None
    if not meta.get("error") and not site_file(out, "videos", record.episode_id, ".mp4").is_file():
        return None
    return meta


def playable(meta: dict[str, Any] | None) -> bool:
    return bool(meta) and not meta.get("error")


def remove_dead_temporaries(out: Path, folder: str) -> None:
    """Half-written files of builds that were killed (``.<name>.<pid>.tmp``, their process gone); a link among them
    goes itself, never what it names."""
    for path in (out / folder).glob(".*.tmp") if (out / folder).is_dir() else ():
        pid = path.name.rsplit(".", 2)[-2]
        if pid.isdigit() and not pid_alive(int(pid)):
            paths.unlink_inside(out, path, "the site")


def _chunks(store: EpisodeStore, keys: Sequence[tuple[str, str]]) -> Iterator[EpisodeRecord]:
    for start in range(0, len(keys), LOAD_CHUNK):
        yield from store.load(keys[start : start + LOAD_CHUNK])


def lacking_videos(store: EpisodeStore, out: Path, keys: Sequence[tuple[str, str]]) -> list[tuple[str, str, int]]:
    """(episode id, policy, steps) of those given that have no video showing the episode as stored now, or one
    whose replay failed (tried again), in the order given."""
    remove_dead_temporaries(out, "videos")
    return [(r.episode_id, r.policy, r.steps) for r in _chunks(store, keys) if not playable(current_meta(out, r))]


def render_videos(
    store: EpisodeStore, out: Path, todo: Sequence[tuple[str, str]], workers: int, progress: bool
) -> tuple[int, int, float]:
    """Replay the (episode id, policy) given (in that order: by base task; from :func:`lacking_videos`); returns
    (rendered, failed, seconds)."""
    from conflictbench.sim.replay import ReplayJob, replay_all

    notes: dict[str, dict[str, Any]] = {}

    def jobs() -> Iterator[ReplayJob]:  # arrays loaded a chunk at a time, as the replays need them
        for r in _chunks(store, todo):
            notes[r.episode_id] = {"episode": episode_digest(r), "warmup_assumed": r.warmup_steps is None}
            sink = Mp4Sink(str(site_file(out, "videos", r.episode_id, ".mp4")), fps=FPS // FRAME_EVERY)
            yield ReplayJob.of(r, sink, FRAME_EVERY)

    bar = CountProgress(len(todo), "videos: episodes replayed", enabled=progress, failures=True)
    rendered = failed = 0
    started = time.perf_counter()
    try:
        with contextlib.closing(replay_all(jobs(), workers=workers)) as replays:  # closed: its processes end
            for result in replays:
                meta = {
                    **notes.pop(result.episode_id),
                    "steps": result.steps if result.error is None else None,
                    "frame_every": FRAME_EVERY,
                    "deviation_m": result.deviation_m,
                    "seconds": round(result.seconds, 2),
                    "bytes": result.bytes,
                    "error": result.error,
                }
                write_atomic(out, site_file(out, "videos", result.episode_id, ".json"), json.dumps(meta))
                rendered += result.error is None
                failed += result.error is not None
                bar.set_postfix(errors=failed)
                bar.update()
    finally:
        bar.close()
    return rendered, failed, time.perf_counter() - started
