"""The viewer's pages and index, written from the store and whatever videos are there at the time: once before
the videos render (the pages are of use without them) and again after."""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from importlib import resources
from itertools import islice
from pathlib import Path

import pandas as pd

from conflictbench.core import ConflictCase, EpisodeRecord, Pair
from conflictbench.core.plugins import Plugins
from conflictbench.metrics import evaluate_pairs
from conflictbench.report.from_store import CHUNK_PAIRS, loaded_pairs, paper_beside
from conflictbench.report.summary import select_metrics
from conflictbench.store import EpisodeStore
from conflictbench.store.paths import unlink_inside

from .episodes import episode_page, references_section
from .site import index_page, pair_page, paper_section
from .videos import current_meta, playable, site_file, write_atomic


@dataclass
class Site:
    store: EpisodeStore
    out: Path
    plugins: Plugins
    pairs: list[Pair]
    rows: pd.DataFrame
    references: list[tuple[str, EpisodeRecord]]
    cases: dict[str, ConflictCase]
    rerun: list[str]
    """The command that built the site, for a page without a video to say how to render it."""
    source: str

    def write(self) -> None:
        """Every pair's page, every reference episode's page and the index, each showing the videos there now."""
        out, store, names = self.out, self.store, [p.conflict.episode_id for p in self.pairs]
        metrics = select_metrics(self.plugins, None)
        measure_names = [m.name for m in metrics]
        with_both: set[str] = set()
        index_rows: list[dict] = []
        frames = []
        loaded = loaded_pairs(store, self.pairs)  # each pair's arrays read once: measured, then its page written
        while chunk := list(islice(loaded, CHUNK_PAIRS)):
            frame = evaluate_pairs(
                [r for r, _ in chunk], [c for _, c in chunk], plugins=self.plugins, metrics=measure_names
            )
            frames.append(frame)
            for (reference, conflict), measured in zip(chunk, frame[measure_names].to_dict("records"), strict=True):
                i = len(index_rows)
                row = {**self.rows.iloc[i].to_dict(), **measured}
                index_rows.append(row)
                metas = {r.episode_id: meta for r in (reference, conflict) if (meta := current_meta(out, r))}
                if all(playable(metas.get(r.episode_id)) for r in (reference, conflict)):
                    with_both.add(conflict.episode_id)
                neighbours = (names[i - 1] if i else None, names[i + 1] if i + 1 < len(names) else None)
                hint = "Render it with: " + shlex.join([*self.rerun, "--pair", conflict.episode_id])
                page = pair_page(row, reference, conflict, self.cases.get(conflict.case_id or ""), metrics, metas,
                                 neighbours, hint)  # fmt: skip
                write_atomic(out, site_file(out, "pairs", conflict.episode_id, ".html"), page)
        shown_references = self._write_reference_pages()
        shown = set(names)
        for stale in (out / "pairs").glob("*.html"):  # pages of pairs this build does not show (filters, a new store)
            if stale.stem not in shown:
                unlink_inside(out, stale, "the site")  # a link goes itself, never what it names
        beside = (
            paper_section(pd.concat(frames, ignore_index=True), metrics, paper_beside(store, self.plugins))
            if frames
            else ""
        )
        listed = references_section(self.references, shown_references)
        write_atomic(out, out / "index.html", index_page(index_rows, metrics, self.source, with_both, beside, listed))
        for name in ("viewer.js", "viewer.css"):
            asset = (resources.files("conflictbench.view") / "assets" / name).read_bytes()
            write_atomic(out, out / "assets" / name, asset)

    def _write_reference_pages(self) -> set[str]:
        """The reference episodes' pages; returns the ids of those with a video."""
        out, shown = self.out, set()
        hint = "Render it with: " + shlex.join([*self.rerun, "--videos", "all"])
        for start in range(0, len(self.references), CHUNK_PAIRS):  # arrays (a video's note is checked against them)
            part = self.references[start : start + CHUNK_PAIRS]
            loaded = {r.episode_id: r for r in self.store.load([(r.episode_id, r.policy) for _, r in part])}
            for label, light in part:
                record = loaded[light.episode_id]
                meta = current_meta(out, record)
                page = episode_page(label, record, meta, hint)
                write_atomic(out, site_file(out, "episodes", record.episode_id, ".html"), page)
                if playable(meta):
                    shown.add(record.episode_id)
        for stale in (out / "episodes").glob("*.html"):
            if stale.stem not in {r.episode_id for _, r in self.references}:
                unlink_inside(out, stale, "the site")
        return shown
