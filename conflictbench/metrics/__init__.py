"""Built-in metrics, registered through ``conflictbench_register_metrics`` like any plugin's."""

from __future__ import annotations

from conflictbench.core import hookimpl

from .outcome import Rate, delta_sr, failure_rate, pcsr, qualified, qualified_failures, rgsr
from .pairs import make_pairs, reference_key


@hookimpl
def conflictbench_register_metrics(register):
    """The process measures (TAR, TS, Early20 TS, AMS) register here."""


__all__ = ["Rate", "delta_sr", "failure_rate", "make_pairs", "pcsr", "qualified", "qualified_failures",
           "reference_key", "rgsr"]
