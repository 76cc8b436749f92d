"""Registered metrics over aligned pairs: every metric a registry holds, built-in or a plugin's, one column each.

:func:`evaluate_pairs` consumes the pairs in chunks and asks every registered metric for its
column: through its ``compute_many(references, conflicts)`` when it has one, else through
``compute(pair)`` pair by pair. Only per-pair scalars are kept between chunks, so memory stays
bounded whatever the number of pairs (the built-ins share one pass of compiled kernels per chunk:
:mod:`.process`).
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Iterable, Iterator, Sequence
from itertools import islice
from typing import Any

import numpy as np
import pandas as pd

from conflictbench.core import EpisodeRecord, MetricSpec, Pair, UserError
from conflictbench.core.plugins import DISABLE_PLUGINS_VARIABLE, Plugins, unknown_choice

#: The module whose hook registers the built-in metrics (the package re-exports it, as a built-in plugin).
BUILTINS_MODULE = "conflictbench.metrics.builtins"
#: Identifies each pair in :func:`evaluate_pairs`'s frame (taken from the conflict episode).
KEY_COLUMNS = (
    "policy",
    "config_hash",
    "policy_settings",
    "suite",
    "task_id",
    "init_state",
    "prompt",
    "seed",
    "case_id",
    "family",
    "level",
    "max_steps",
    "conflict_suite",
)
CHUNK_PAIRS = 2048


def _value(v: Any) -> float | None:
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


# -- public API ----------------------------------------------------------------------------------
@functools.lru_cache(maxsize=1)
def default_plugins() -> Plugins:
    """The built-in metrics plus every installed plugin not disabled (``CONFLICTBENCH_DISABLE_PLUGINS``), created
    once (metrics' registry is then cached): the metrics ``conflictbench.plugins()`` registers, without the
    built-in policies and suites, and without that function, which loads this package as a plugin (a built-in
    plugin never imports the package that loads it)."""
    return Plugins((BUILTINS_MODULE,), disabled=os.environ.get(DISABLE_PLUGINS_VARIABLE, "").split(","))


def metric_specs(plugins=None, names: Sequence[str] | None = None) -> list[MetricSpec]:
    """The registered metrics in the registry's order, or those named (UserError if one is not registered)."""
    registered = (plugins or default_plugins()).metrics()
    if names is None:
        return list(registered.values())
    for name in names:
        if name not in registered:
            raise UserError(unknown_choice("metric", name, registered))
    return [registered[n] for n in names]


def _chunks(
    references: Iterable[EpisodeRecord], conflicts: Iterable[EpisodeRecord], size: int
) -> Iterator[tuple[list[EpisodeRecord], list[EpisodeRecord]]]:
    pairs = zip(references, conflicts, strict=True)
    while chunk := list(islice(pairs, size)):
        yield [r for r, _ in chunk], [c for _, c in chunk]


def _warn_once(spec: MetricSpec, failed: set[str], problem: str) -> None:
    if spec.name not in failed:  # a broken third-party metric must not sink the report
        failed.add(spec.name)
        warnings.warn(f"metric {spec.name!r} ({spec.plugin}) {problem}; counted as undefined", stacklevel=4)


def _column(
    spec: MetricSpec, references: list[EpisodeRecord], conflicts: list[EpisodeRecord], failed: set[str]
) -> np.ndarray:
    """One metric over a chunk, float64 with NaN where undefined (None, NaN, infinite or raised)."""
    n = len(references)
    if spec.compute_many is not None:
        try:
            values = spec.compute_many(references, conflicts)
            out = np.array(
                [math.nan if v is None else v for v in values] if not isinstance(values, np.ndarray) else values,
                dtype=np.float64,
            )
        except Exception as exc:
            _warn_once(spec, failed, f"raised {type(exc).__name__}: {exc}")
            return np.full(n, math.nan)
        if out.shape != (n,):
            _warn_once(spec, failed, f"gave {out.size} values for {n} pairs")
            return np.full(n, math.nan)
        out[~np.isfinite(out)] = math.nan
        return out
    out = np.full(n, math.nan)
    for i, (ref, con) in enumerate(zip(references, conflicts)):
        try:
            value = _value(spec.compute(Pair(reference=ref, conflict=con)))
        except Exception as exc:
            _warn_once(spec, failed, f"raised {type(exc).__name__}: {exc}")
            value = None
        out[i] = math.nan if value is None else value
    return out


def evaluate_pairs(
    references: Iterable[EpisodeRecord],
    conflicts: Iterable[EpisodeRecord],
    *,
    plugins=None,
    metrics: Sequence[str] | None = None,
    chunk_size: int = CHUNK_PAIRS,
) -> pd.DataFrame:
    """One row per aligned (reference, conflict) pair: the pair's keys, both outcomes, every metric.

    Columns: :data:`KEY_COLUMNS` (from the conflict episode), ``reference_success``,
    ``conflict_success``, ``reference_episode``, ``conflict_episode``, ``same_targets`` (both rollouts
    have the same target set: where not, TAR is undefined), then every registered
    metric (or only ``metrics``) in :func:`metric_specs`' order, as float64 with NaN where a
    measure is undefined. The inputs may be generators: they are consumed in
    chunks of ``chunk_size`` pairs, so only per-pair scalars are held.
    """
    specs = metric_specs(plugins, metrics)
    frames, failed = [], set()
    for refs, cons in _chunks(references, conflicts, chunk_size):
        columns: dict[str, Any] = {key: [getattr(c, key) for c in cons] for key in KEY_COLUMNS}
        columns["reference_success"] = np.fromiter((bool(r.success) for r in refs), dtype=bool, count=len(refs))
        columns["conflict_success"] = np.fromiter((bool(c.success) for c in cons), dtype=bool, count=len(cons))
        columns["reference_episode"] = [r.episode_id for r in refs]
        columns["conflict_episode"] = [c.episode_id for c in cons]
        columns["same_targets"] = np.fromiter(
            (set(r.target_names) == set(c.target_names) for r, c in zip(refs, cons)), dtype=bool, count=len(refs)
        )
        for spec in specs:
            columns[spec.name] = _column(spec, refs, cons, failed)
        frames.append(pd.DataFrame(columns))
    if not frames:
        empty = {key: pd.Series([], dtype=object) for key in KEY_COLUMNS}
        empty.update(
            {
                "reference_success": pd.Series([], dtype=bool),
                "conflict_success": pd.Series([], dtype=bool),
                "reference_episode": pd.Series([], dtype=object),
                "conflict_episode": pd.Series([], dtype=object),
                "same_targets": pd.Series([], dtype=bool),
            }
        )
        empty.update({s.name: pd.Series([], dtype=np.float64) for s in specs})
        return pd.DataFrame(empty)
    return pd.concat(frames, ignore_index=True) if len(frames) > 1 else frames[0]


def pair_metrics(reference: EpisodeRecord, conflict: EpisodeRecord, *, plugins=None) -> dict[str, float | None]:
    """Every registered metric of one pair (None: undefined)."""
    row = evaluate_pairs([reference], [conflict], plugins=plugins).iloc[0]
    return {spec.name: _value(row[spec.name]) for spec in metric_specs(plugins)}
