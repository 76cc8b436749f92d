"""Built-in metrics, registered through ``conflictbench_register_metrics`` like any plugin's.

Public API: :func:`pair_metrics` (one pair -> dict), :func:`evaluate_pairs` (aligned lists ->
one DataFrame row per pair, the fast path), :func:`aggregate` and the P0 - P1 helpers over that
frame, and the outcome rates over :class:`~conflictbench.core.Pair` lists.
"""

from __future__ import annotations

from .aggregate import GROUPINGS, aggregate, prompt_couples, prompt_differences, qualified_failure_mask, with_model
from .builtins import DESCRIPTIONS
from .builtins import conflictbench_register_metrics as conflictbench_register_metrics  # the built-in plugin's hook
from .outcome import Rate, delta_sr, failure_rate, pcsr, qualified, qualified_failures, rgsr
from .pairs import make_pairs, reference_key
from .plain import EARLY_STEPS, EPS, SIGMA
from .process import BUILTIN_METRICS, dtw
from .registered import evaluate_pairs, metric_specs, pair_metrics

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
