"""The grounding family's rule: every substituted referent is absent from the scene."""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.scene.lexicon import absence_problem
from conflictbench.tasks.scene.lexicon import concept as absent_concept
from conflictbench.tasks.scene.task_model import TaskModel


def check_absent(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    for r in case.witness.get("referents", []):
        text = str(r.get("text", ""))
        if not text or text not in case.instruction:
            out.append(f"referent {text!r} is not in the instruction")
            continue
        known = absent_concept(str(r.get("concept", "")))
        synonyms = known.synonyms if known else ()
        phrase = text.removeprefix("the ")
        why = absence_problem(phrase, synonyms, model.problem)
        if why:
            out.append(f"referent {text!r} is not absent: {why}")
    return out
