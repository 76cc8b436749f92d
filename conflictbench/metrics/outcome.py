"""Outcome measures over a set of pairs: PCSR, RGSR, dSR and FR, each with its counts."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from conflictbench.core import Pair


@dataclass(frozen=True)
class Rate:
    k: int
    n: int

    @property
    def value(self) -> float | None:
        return self.k / self.n if self.n else None

    def __str__(self) -> str:
        return f"{100 * self.k / self.n:.1f}% ({self.k}/{self.n})" if self.n else "n/a (0/0)"


def reference_succeeded(pair: Pair) -> bool:
    return bool(pair.reference.success)


def conflict_succeeded(pair: Pair) -> bool:
    """y-: the conflict rollout completed the ORIGINAL goal of the base task."""
    return bool(pair.conflict.success)


def pcsr(pairs: Sequence[Pair]) -> Rate:
    return Rate(sum(reference_succeeded(p) for p in pairs), len(pairs))


def rgsr(pairs: Sequence[Pair]) -> Rate:
    return Rate(sum(conflict_succeeded(p) for p in pairs), len(pairs))


def delta_sr(pairs: Sequence[Pair]) -> float | None:
    if not pairs:
        return None
    return (pcsr(pairs).k - rgsr(pairs).k) / len(pairs)


def qualified(pairs: Sequence[Pair]) -> list[Pair]:
    """D_Q: pairs whose reference succeeded (the policy can do the base task from this state)."""
    return [p for p in pairs if reference_succeeded(p)]


def qualified_failures(pairs: Sequence[Pair]) -> list[Pair]:
    """D_QF: qualified pairs whose conflict rollout did not complete the original goal."""
    return [p for p in qualified(pairs) if not conflict_succeeded(p)]


def failure_rate(pairs: Sequence[Pair]) -> Rate:
    """FR = |D_QF| / |D_Q| (n/a when D_Q is empty)."""
    return Rate(len(qualified_failures(pairs)), len(qualified(pairs)))
