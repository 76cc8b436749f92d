"""The grounding family's rules: every substituted referent is absent, and it matters.

Per referent the witness gives ``step``, ``role``, ``text``, ``concept``, ``source`` and ``replaces``:

- the role is the step's manipulated ``object`` (for a state step, the operated drawer or
  appliance), its ``destination`` or its ``receptacle``; a landmark alone is never a referent;
- ``replaces`` is the entity of that step the referent stands in for: one of the step's objects
  for ``object``, the step's goal destination (or its holder) for the other roles;
- the referent is in the text of its step, and that step is original, except an added step's object;
- it is absent, by its ``source``: ``libero`` (a LIBERO category not in this scene, sharing no name,
  synonym, near-synonym, part, hypernym or head noun with anything present), ``attribute`` (a wrong
  colour of a present category, clearly different from every colour present), ``out_of_domain``
  (an item of the absent-referent table, judged the same way as ``libero``);
- a ``receptacle`` referent (other than a wrong colour) is no word a reader could map onto an open
  receptacle present (:func:`~conflictbench.tasks.scene.lexicon.receptacle_problem`: "the bucket"
  reads as the desk caddy);
- at L2 the two referents replace two DIFFERENT roles of the one step: the object and its
  destination or receptacle; no referent repeats a concept of another.
"""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.operators.grounding import referent_synonyms
from conflictbench.tasks.scene.affordances import load_table
from conflictbench.tasks.scene.lexicon import absence_problem, attribute_problem, receptacle_problem, scene_categories
from conflictbench.tasks.scene.lexicon import concept as absent_concept
from conflictbench.tasks.scene.task_model import TaskModel

ROLES = ("object", "destination", "receptacle")
SOURCES = ("libero", "attribute", "out_of_domain")


def _source_problem(r: dict, phrase: str, model: TaskModel) -> str | None:
    source, concept = r.get("source"), str(r.get("concept", ""))
    present = set(scene_categories(model.problem))
    if source == "attribute":
        if concept not in present:
            return f"a wrong attribute must be of a category in the scene, not {concept!r}"
        return attribute_problem(phrase, model.problem)
    if source == "libero":
        table = load_table()
        if concept not in table or concept in present or phrase not in table[concept].names:
            return f"{phrase!r} is not the name of a LIBERO category absent from this scene"
        synonyms = table[concept].synonyms
    else:
        known = absent_concept(concept)
        synonyms = known.synonyms if known else ()
    return absence_problem(phrase, synonyms, model.problem)


def _stands_in_for(r: dict, case: ConflictCase, model: TaskModel) -> str | None:
    index = int(r["step"]) - 1
    replaces, role = r.get("replaces"), r.get("role")
    if not replaces:
        return "the witness does not say which scene entity the referent replaces"
    w = case.witness
    if role == "object":
        allowed = set(w.get("step_entities", [[]] * len(w["steps"]))[index])
    else:
        allowed = {str(lit[2]) for lit in w["step_goals"][index] if len(lit) == 3}
    allowed |= {model.parent(e) for e in allowed}
    if replaces not in allowed:
        return f"{replaces!r} is not the {role} of step {index + 1}"
    if w["step_roles"][index] == "added" and role != "object":
        return f"step {index + 1} is an added step: only its object may be replaced"
    return None


def check_absent(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    refs = case.witness.get("referents", [])
    for r in refs:
        text = str(r.get("text", ""))
        if not text or text not in case.instruction:
            out.append(f"referent {text!r} is not in the instruction")
            continue
        if r.get("role") not in ROLES:
            out.append(
                f"referent {text!r} has role {r.get('role')!r}: only the manipulated object, the destination or "
                "the receptacle may be absent (a missing landmark alone is not a grounding conflict)"
            )
            continue
        if r.get("source") not in SOURCES:
            out.append(f"referent {text!r} has source {r.get('source')!r}; expected one of {', '.join(SOURCES)}")
            continue
        if text not in case.witness["steps"][int(r["step"]) - 1]:
            out.append(f"referent {text!r} is not in the text of step {r['step']}")
        why = _stands_in_for(r, case, model) or _source_problem(r, text.removeprefix("the "), model)
        if not why and r.get("role") == "receptacle" and r.get("source") != "attribute":
            phrase, concept = text.removeprefix("the "), str(r.get("concept", ""))
            synonyms = referent_synonyms(concept, str(r.get("source")))
            why = receptacle_problem(phrase, synonyms, model.problem)
        if why:
            out.append(f"referent {text!r} is not absent or not a referent of the task: {why}")
    concepts = [(r.get("concept"), r.get("text")) for r in refs if isinstance(r, dict)]
    if len(set(concepts)) < len(concepts):
        out.append("two referents repeat one concept")
    if case.level == "L2":
        roles = sorted(str(r.get("role")) for r in refs)
        if len(set(roles)) < len(roles) or "object" not in roles:
            out.append(
                f"L2 replaces roles {roles}: its two factors must replace two different roles of the step, "
                "the object and its destination or receptacle"
            )
    return out
