"""Rules about the suite as a whole, not one case: no exact instruction twice within a LIBERO suite
(the same words for two scenes of one suite test the same reading twice), and each family's own
composition rules for a whole suite (a family module may define ``suite_problems(cases, models)``)."""

from __future__ import annotations

import importlib
from collections.abc import Sequence

from conflictbench.core import FAMILIES, ConflictCase

from .text import normalise


def duplicate_problems(cases: Sequence[ConflictCase]) -> list[tuple[str, str]]:
    out, seen = [], {}
    for case in cases:
        key = (case.suite, normalise(case.instruction))
        if key in seen:
            out.append((case.case_id, f"same instruction as {seen[key]} within {case.suite}"))
        seen.setdefault(key, case.case_id)
    return out


def suite_problems(cases: Sequence[ConflictCase], ctx, *, composition: bool = True) -> list[tuple[str, str]]:
    """Duplicates always; the families' composition rules (kinds per cell, skeleton shares) only for
    a whole suite (``composition``), not for an export of some of its cases."""
    out = duplicate_problems(cases)
    if not composition:
        return out
    for family in FAMILIES:
        module = importlib.import_module(f"conflictbench.tasks.validation.{family}")
        check = getattr(module, "suite_problems", None)
        mine = [c for c in cases if c.family == family]
        if check is not None and mine:
            models = {(c.suite, c.task_id): ctx.model((c.suite, c.task_id)) for c in mine}
            out += check(mine, models)
    return out
