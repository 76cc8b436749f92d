"""Built-in metrics, registered through ``conflictbench_register_metrics`` like any plugin's.

Public API: :func:`pair_metrics` (one pair -> dict), :func:`evaluate_pairs` (aligned lists ->
one DataFrame row per pair, the fast path), :func:`aggregate` and the P0 - P1 helpers over that
frame, and the outcome rates over :class:`~conflictbench.core.Pair` lists.
"""

from __future__ import annotations

from conflictbench.core import hookimpl

from .aggregate import GROUPINGS, aggregate, prompt_couples, prompt_differences, qualified_failure_mask, with_model
from .builtins import DESCRIPTIONS, register_builtins
from .outcome import Rate, delta_sr, failure_rate, pcsr, qualified, qualified_failures, rgsr
from .pairs import make_pairs, reference_key
from .plain import EARLY_STEPS, EPS, SIGMA
from .process import BUILTIN_METRICS, dtw, evaluate_pairs, metric_specs, pair_metrics


@hookimpl
def conflictbench_register_metrics(register):
    """TAR, TS, Early20 TS and AMS, through the same hook and arguments third-party metrics use."""
    register_builtins(register)


__all__ = [
    "BUILTIN_METRICS",
    "DESCRIPTIONS",
    "EARLY_STEPS",
    "EPS",
    "GROUPINGS",
    "Rate",
    "SIGMA",
    "aggregate",
    "delta_sr",
    "dtw",
    "evaluate_pairs",
    "failure_rate",
    "make_pairs",
    "metric_specs",
    "pair_metrics",
    "pcsr",
    "prompt_couples",
    "prompt_differences",
    "qualified",
    "qualified_failure_mask",
    "qualified_failures",
    "reference_key",
    "rgsr",
    "with_model",
]
