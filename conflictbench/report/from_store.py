"""Reports straight from an episode store, streaming: at paper scale (8 models x 14,530 episodes)
the arrays of every episode would not fit in memory, so only one chunk of them is loaded at a time.

The key columns of every episode are read first (cheap), pairs are formed on them, then the
arrays are loaded chunk by chunk for the metric kernels; references, shared by many pairs, are
loaded once and kept.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from itertools import tee

import pandas as pd

from conflictbench.core import EpisodeRecord, MetricSpec, Pair
from conflictbench.core.plugins import Plugins
from conflictbench.metrics import evaluate_pairs, with_model
from conflictbench.store import EpisodeStore
from conflictbench.store.check import going_on
from conflictbench.store.schema import ARRAY_COLUMNS, SCHEMA, normalize_scalars

from .paper import declared_paper_models
from .summary import pair_up, report_frame, select_metrics

KEY_COLUMNS = [name for name in SCHEMA.names if name not in ARRAY_COLUMNS]
CHUNK_PAIRS = 2048


def light_records(store: EpisodeStore, episode_ids: Iterable[str] | None = None) -> list[EpisodeRecord]:
    """Every episode's keys, outcome and provenance, without its arrays."""
    rows = store.read_table(columns=KEY_COLUMNS, episode_ids=episode_ids).to_pylist()
    for row in rows:
        normalize_scalars(row)
    return [EpisodeRecord(**row) for row in rows]


def loaded_pairs(
    store: EpisodeStore, pairs: Sequence[Pair], chunk: int = CHUNK_PAIRS
) -> Iterator[tuple[EpisodeRecord, EpisodeRecord]]:
    """The pairs again, with arrays, ``chunk`` conflict episodes at a time."""
    references: dict[str, EpisodeRecord] = {}
    for start in range(0, len(pairs), chunk):
        part = pairs[start : start + chunk]
        wanted = {p.conflict.episode_id: p.conflict.policy for p in part}
        wanted.update(
            {p.reference.episode_id: p.reference.policy for p in part if p.reference.episode_id not in references}
        )
        loaded = {r.episode_id: r for r in store.load(wanted.items())}
        for pair in part:
            references.setdefault(pair.reference.episode_id, loaded.get(pair.reference.episode_id))
        for pair in part:
            yield references[pair.reference.episode_id], loaded[pair.conflict.episode_id]


def paper_beside(store: EpisodeStore, plugins: Plugins) -> dict[tuple[str, str], str]:
    """(policy, settings hash) -> the paper's model, for the store's runs declared to be one of the paper's
    checkpoints (``model.published=<entry>``, recorded in the store)."""
    from conflictbench.store.declarations import declarations

    return declared_paper_models(declarations(store.root), plugins.published_results())


def store_frame(
    store: EpisodeStore,
    plugins: Plugins,
    metrics: Sequence[MetricSpec],
    *,
    suite: str | None = None,
    suite_cases: Iterable[str] | None = None,
    models: Iterable[str] | None = None,
) -> tuple[pd.DataFrame, list[str]]:
    """The per-pair frame (with ``model``) of the store's pairs, only those of ``models`` (labels as the report
    gives them) where named, and every model label the store has (of ``suite``, as :func:`report_store`). An
    episode met damaged by its arrays is set aside and the frame made again without it (``check.going_on``)."""
    suite_cases, models = _again(suite_cases), _again(models)  # read on every try
    return going_on(lambda: _store_frame(store, plugins, metrics, suite, suite_cases, models))


def _store_frame(
    store: EpisodeStore,
    plugins: Plugins,
    metrics: Sequence[MetricSpec],
    suite: str | None,
    suite_cases: Iterable[str] | None,
    models: Iterable[str] | None,
) -> tuple[pd.DataFrame, list[str]]:
    pairs, _ = pair_up(light_records(store), suite, suite_cases)
    keys = pd.DataFrame(
        {
            "policy": [p.conflict.policy for p in pairs],
            "config_hash": [p.conflict.config_hash for p in pairs],
            "policy_settings": [p.conflict.policy_settings for p in pairs],
        }
    )
    labels = with_model(keys)["model"].tolist() if len(pairs) else []
    wanted = None if models is None else set(models)
    chosen = [(p, label) for p, label in zip(pairs, labels) if wanted is None or label in wanted]
    first, second = tee(loaded_pairs(store, [p for p, _ in chosen]))
    frame = evaluate_pairs((r for r, _ in first), (c for _, c in second), plugins=plugins,
                           metrics=[m.name for m in metrics])  # fmt: skip
    frame["model"] = [label for _, label in chosen]
    return frame, sorted(set(labels))


def report_store(
    store: EpisodeStore,
    plugins: Plugins,
    *,
    episode_ids: Iterable[str] | None = None,
    metrics: Sequence[str] | None = None,
    chunk: int = CHUNK_PAIRS,
    suite: str | None = None,
    suite_cases: Iterable[str] | None = None,
    **options,
) -> dict[str, pd.DataFrame]:
    """:func:`~conflictbench.report.summary.report_records` for the episodes of a store (or some of them); with
    ``suite`` (``name version``) only that suite's conflict episodes, the others counted in one line (and with
    ``suite_cases``, the ids that suite plays, the others' cases it no longer has named). An episode met damaged
    by its arrays is set aside, named in one line, and the report made again without it (``check.going_on``)."""
    episode_ids, suite_cases = _again(episode_ids), _again(suite_cases)  # read on every try
    return going_on(lambda: _report_store(store, plugins, episode_ids, metrics, chunk, suite, suite_cases, options))


def _again(values: Iterable[str] | None) -> list[str] | None:
    return None if values is None else list(values)


def _report_store(store, plugins, episode_ids, metrics, chunk, suite, suite_cases, options) -> dict[str, pd.DataFrame]:
    chosen = select_metrics(plugins, metrics)
    pairs, counts = pair_up(light_records(store, episode_ids), suite, suite_cases)
    options.setdefault("paper", paper_beside(store, plugins))
    first, second = tee(loaded_pairs(store, pairs, chunk))
    frame = evaluate_pairs(
        (r for r, _ in first),
        (c for _, c in second),
        plugins=plugins,
        metrics=[m.name for m in chosen],
        chunk_size=chunk,
    )
    return report_frame(frame, counts, chosen, **options)
