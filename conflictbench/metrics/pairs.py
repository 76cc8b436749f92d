"""Forming pairs: each conflict episode with the reference episode it shares everything with."""

from __future__ import annotations

from collections.abc import Iterable

from conflictbench.core import EpisodeRecord, Pair


def reference_key(record: EpisodeRecord) -> tuple:
    """Same policy (and settings), base task, initial state, prompt condition and seed."""
    return (
        record.policy,
        record.config_hash,
        record.suite,
        record.task_id,
        record.init_state,
        record.prompt,
        record.seed,
    )


def make_pairs(records: Iterable[EpisodeRecord]) -> tuple[list[Pair], list[EpisodeRecord]]:
    """Pair every conflict episode with its reference; also return conflicts whose reference is missing.

    A reference shared by k conflict episodes appears in k pairs (and counts k times in PCSR).
    """
    records = list(records)
    references = {reference_key(r): r for r in records if r.is_reference}
    pairs, orphans = [], []
    for record in records:
        if record.is_reference:
            continue
        ref = references.get(reference_key(record))
        if ref is None:
            orphans.append(record)
        else:
            pairs.append(Pair(reference=ref, conflict=record))
    return pairs, orphans
