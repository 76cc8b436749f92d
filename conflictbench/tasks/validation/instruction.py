"""The instruction family's rule: every claimed pair of requirements really contradicts."""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.operators.contradictions import contradiction, literal_entities
from conflictbench.tasks.scene.task_model import TaskModel

from .text import _named_or_pronoun


def check_contradiction(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    w, out = case.witness, []
    reqs = {r.get("id"): r for r in w.get("requirements", []) if isinstance(r, dict)}
    for r in reqs.values():
        lit = r.get("literal")
        if not isinstance(lit, list) or len(lit) < 3 or lit[0] not in ("goal", "avoid", "keep", "do"):
            out.append(f"requirement {r.get('id')}: malformed literal {lit!r}")
            continue
        if r.get("text", "") not in case.instruction:
            out.append(f"requirement {r.get('id')}: text {r.get('text')!r} is not in the instruction")
        for e in literal_entities(lit):
            if e not in model.facts.entities and e not in model.problem.fixtures:
                out.append(f"requirement {r.get('id')}: {e!r} is not in the scene")
            elif not _named_or_pronoun(model, e, r.get("text", ""), case.instruction):
                out.append(f"requirement {r.get('id')}: its text does not name {e}")
    if not w.get("conflicts"):
        out.append("the witness lists no contradicting requirements")
    for pair in w.get("conflicts", []):
        if not (isinstance(pair, list) and len(pair) == 2 and all(p in reqs for p in pair)):
            out.append(f"conflict {pair!r} does not name two listed requirements")
            continue
        a, b = (reqs[p].get("literal") for p in pair)
        if (
            isinstance(a, list)
            and isinstance(b, list)
            and len(a) >= 3
            and len(b) >= 3
            and contradiction(a, b, model.facts, states) is None
        ):
            out.append(f"requirements {pair[0]} and {pair[1]} do not contradict ({a} / {b})")
    return out
