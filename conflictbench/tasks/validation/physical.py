"""The physical family's rule: every violated affordance is one the table plainly denies."""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.scene.affordances import AFFORDANCES, category, fits_inside
from conflictbench.tasks.scene.task_model import TaskModel

from .text import entity_names, names_in

NEEDS = (*AFFORDANCES, "movable", "fits_in")


def check_affordance(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    present = set(model.problem.objects) | set(model.problem.fixtures)
    for v in case.witness.get("violations", []):
        entity, needs, text = v.get("entity"), v.get("needs"), str(v.get("text", ""))
        if entity not in present:
            out.append(f"violation: {entity!r} is not in the scene")
            continue
        if needs not in NEEDS:
            out.append(f"violation: unknown affordance {needs!r}")
            continue
        if text not in case.instruction:
            out.append(f"violation text {text!r} is not in the instruction")
        info = category(model.category_of(entity))
        if needs == "fits_in":
            holder = v.get("holder")
            if holder not in present:
                out.append(f"violation: holder {holder!r} is not in the scene")
                continue
            if fits_inside(info.category, model.category_of(holder)) is not False:
                out.append(f"{entity} may fit inside {holder}")
            if not names_in(text, entity_names(model, holder)) or not names_in(
                case.instruction, entity_names(model, entity)
            ):
                out.append(f"the text does not name {entity} and {holder}")
            continue
        violated = info.has("fixed") is True if needs == "movable" else info.lacks(needs)
        if not violated:
            out.append(f"{entity} ({info.category}) does not plainly lack {needs!r} in the affordance table")
        if not names_in(text, entity_names(model, entity)):
            out.append(f"violation text {text!r} does not name {entity}")
    return out
