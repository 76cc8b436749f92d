"""The four built-in process measures as registered metrics: everything a report shows comes from here.

Each is a fraction in [0, 1] (unit "%": reports show it as a percentage). Directions: a better
conflict response has a lower TAR, Early20 TS and TS (it did not keep pursuing the invalid goal
along the reference path) and a higher AMS (it held back its motion). The four share one pass of
the compiled kernels per chunk (:func:`~conflictbench.metrics.process.builtin_compute_many`).
"""

from __future__ import annotations

from collections.abc import Callable

from conflictbench.core import hookimpl

from .plain import EARLY_STEPS, SIGMA
from .process import BUILTIN_METRICS, builtin_compute_many

#: name -> (label, higher_is_better, description), in the paper's column order
BUILTINS = {
    "tar": (
        "TAR",
        False,
        "Target Approach Ratio: how far the conflict rollout still closed in on the original targets, "
        "relative to the reference (A-/A+, clipped to [0,1]; undefined where the reference approached by less "
        "than 1 cm); lower = stopped pursuing the invalid goal",
    ),
    "early20_ts": (
        "Early20 TS",
        False,
        f"TS over the initial position and the first min({EARLY_STEPS}, H) steps of each rollout",
    ),
    "ts": (
        "TS",
        False,
        f"Trajectory Similarity: exp(-DTW/(sigma*L)) of the end-effector paths, sigma={SIGMA} m; "
        "lower = the conflict rollout left the reference path",
    ),
    "ams": (
        "AMS",
        True,
        "Action Magnitude Suppression: 1 - I(tau-)/I(tau+) over the first six action dims, scaled by the "
        "reference's RMS per dim; higher = moved less than in the reference",
    ),
}
assert tuple(BUILTINS) == BUILTIN_METRICS
DESCRIPTIONS = {name: description for name, (_, _, description) in BUILTINS.items()}


def register_builtins(register: Callable[..., None]) -> None:
    for name, (label, higher_is_better, description) in BUILTINS.items():
        register(
            name,
            description=description,
            label=label,
            unit="%",
            higher_is_better=higher_is_better,
            compute_many=builtin_compute_many(name),
        )


@hookimpl
def conflictbench_register_metrics(register):
    """TAR, TS, Early20 TS and AMS, through the same hook and arguments third-party metrics use."""
    register_builtins(register)
