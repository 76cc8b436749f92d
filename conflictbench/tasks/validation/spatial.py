"""The spatial family's rule: every presupposed relation is false for every entity its words denote."""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.scene.facts import RELATIONS
from conflictbench.tasks.scene.task_model import TaskModel

from .text import names_in

RELATION_WORDS = {
    "left_of": ("left",),
    "right_of": ("right",),
    "in_front_of": ("in front of",),
    "behind": ("behind",),
    "next_to": ("next to", "beside"),
    "on": ("on",),
    "in": ("in", "inside"),
    "between": ("between",),
}


def check_relation(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    facts = model.facts
    for r in case.witness.get("relations", []):
        rel, text = r.get("relation"), str(r.get("text", ""))
        if rel not in RELATIONS:
            out.append(f"unknown relation {rel!r}")
            continue
        if text not in case.instruction:
            out.append(f"relation text {text!r} is not in the instruction")
        args = [r.get("subject", {})] + list(r.get("landmarks", []))
        if len(args) != (3 if rel == "between" else 2):
            out.append(f"{rel} takes {3 if rel == 'between' else 2} arguments, got {len(args)}")
            continue
        groups = []
        for arg in args:
            listed = set(arg.get("entities", []))
            unknown = listed - set(facts.entities)
            if not listed or unknown:
                out.append(f"relation {rel}: entities {sorted(unknown) or '(none)'} are not in the scene")
                break
            missing = model.candidates(str(arg.get("phrase", ""))) - listed
            if missing:
                out.append(f"relation {rel}: {arg.get('phrase')!r} could also mean {', '.join(sorted(missing))}")
            if not names_in(text, {str(arg.get("phrase", ""))}):
                out.append(f"relation text {text!r} does not name {arg.get('phrase')!r}")
            groups.append(sorted(listed))
        else:
            if not any(names_in(text, {w}) for w in RELATION_WORDS[rel]):
                out.append(f"relation text {text!r} does not say {rel.replace('_', ' ')}")
            for combo in _product(groups):
                true_in = facts.holds(rel, *combo) & states
                if true_in:
                    out.append(f"{rel}{tuple(combo)} holds in initial state(s) {sorted(true_in)[:5]}")
    return out


def _product(groups: list[list[str]]) -> list[list[str]]:
    combos: list[list[str]] = [[]]
    for g in groups:
        combos = [c + [x] for c in combos for x in g if x not in c]
    return combos
