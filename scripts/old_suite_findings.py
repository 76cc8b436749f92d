"""What the current validator rejects in an older suite file (1.x), rule by rule.

Suite 1.x witnesses do not say which steps are original, what each achieves or what each acts on;
this script infers those fields the way the 1.x generator built its frames (an added step is a
"move X aside", or an opening / switching-on of something the base task does not touch; the pick-up
half of a split pick-and-place achieves nothing; the other steps take the base task's subgoals
in order), then runs every case rule and the suite rules, and counts the rejected cases per rule.

    git show REV:conflictbench/tasks/data/suite.jsonl > old.jsonl
    .venv/bin/python scripts/old_suite_findings.py old.jsonl
"""

from __future__ import annotations

import dataclasses
import re
import sys
from collections import Counter, defaultdict

from conflictbench.tasks.suite.file import load_suite
from conflictbench.tasks.validation.rules import new_context, validate_case
from conflictbench.tasks.validation.suite_rules import suite_problems

ADDED = re.compile(r"\b(out of the way|aside|to one side)\b")
RULES = [  # (label, substring of the validator's reason)
    ("unobservable: a conflict only after the original task", "come after the original task's first step"),
    ("truncated original: a subgoal dropped", "drops the base task's subgoal"),
    ("a step does not name its goal's entities", "which its goal"),
    ("ambiguous or misplaced pronoun", "pronoun"),
    ("contradiction satisfiable by some order", "satisfiable"),
    ("contradiction not derivable", "do not contradict"),
    ("grounding: role not object/destination/receptacle", "role"),
    ("grounding: referent not absent / a synonym", "not absent"),
    ("spatial: margin too small for a camera", "margin"),
    ("spatial: an earlier step acts on the relation's entities", "earlier step"),
    ("spatial: relation holds", "holds in initial state"),
    ("physical: violation not plainly denied", "does not plainly lack"),
    ("same text twice within a LIBERO suite", "same instruction as"),
]


def _upgrade(case, model):
    """The 1.x case with the step fields inferred (see the module docstring)."""
    steps = case.witness.get("steps", [])
    targets = {e for s in model.steps for e in (*s.objects, s.dest) if e}
    names = lambda e: model.entity_names(e) | model.entity_names(model.parent(e))  # noqa: E731
    roles, goals, entities = [], [], []
    base = list(model.steps)
    for text in steps:
        acts_on_target = any(any(n in text for n in names(t)) for t in targets)
        added = bool(ADDED.search(text)) or not acts_on_target
        roles.append("added" if added else "original")
        goals.append([])
        entities.append([])
    originals = [i for i, r in enumerate(roles) if r == "original"]
    pick = [i for i in originals if i + 1 < len(steps) and re.match(r"(place|put|set) (it|them)\b", steps[i + 1])]
    placing = [i for i in originals if i not in pick]
    for j, i in enumerate(placing):
        if len(placing) == len(base):
            step = base[j]
        else:
            step = next((s for s in base if any(n in steps[i] for o in s.objects for n in names(o))), base[0])
        goals[i] = [list(a) for a in step.goal]
        entities[i] = list(step.objects)
    witness = {**case.witness, "step_roles": roles, "step_goals": goals, "step_entities": entities}
    if case.family == "grounding":
        for r in witness.get("referents", []):
            i = int(r.get("step", 1)) - 1
            step = next((s for s in base if [list(a) for a in s.goal] == goals[i]), base[0])
            r.setdefault("replaces", step.objects[0] if r.get("role") == "object" else step.dest)
    return dataclasses.replace(case, witness=witness)


def main(path: str) -> None:
    suite = load_suite(path)
    ctx = new_context()
    cases = [_upgrade(c, ctx.model((c.suite, c.task_id))) for c in suite.accepted()]
    by_rule: dict[str, set[str]] = defaultdict(set)
    cells: Counter = Counter()
    rejected: set[str] = set()
    reasons = [(c.case_id, r) for c in cases for r in validate_case(c, ctx)] + suite_problems(cases, ctx)
    family_of = {c.case_id: (c.family, c.level) for c in cases}
    for case_id, reason in reasons:
        rejected.add(case_id)
        label = next((label for label, needle in RULES if needle in reason), "other: " + reason[:60])
        by_rule[label].add(case_id)
    for case_id in rejected:
        cells[family_of[case_id]] += 1
    print(f"{suite.name} {suite.version}: {len(cases)} usable cases, {len(rejected)} rejected by at least one rule")
    for label, ids in sorted(by_rule.items(), key=lambda kv: -len(kv[1])):
        print(f"  {len(ids):5d}  {label}")
    print("rejected per family x level:")
    for (family, level), n in sorted(cells.items()):
        total = sum(1 for c in cases if (c.family, c.level) == (family, level))
        print(f"  {family:<12} {level}  {n:4d} / {total}")


if __name__ == "__main__":
    main(sys.argv[1])
