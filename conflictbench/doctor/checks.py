"""The result every ``conflictbench doctor`` check gives: one line, passed or not."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass


@dataclass(frozen=True)
class Check:
    name: str  # "physics", "rendering", "stack", "model", ...
    passed: bool  # False makes `doctor` exit 1
    text: str  # the one line's message


def print_checks(checks: Iterable[Check], stream) -> bool:
    """One line per check, ``name ok|FAIL text``; whether all passed."""
    passed = True
    for check in checks:
        print(f"{check.name:<10} {'ok  ' if check.passed else 'FAIL'} {check.text}", file=stream, flush=True)
        passed = passed and check.passed
    return passed
