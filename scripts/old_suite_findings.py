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
RULES = [  # (label, substring of the validator's reason); the first that matches names the rule
    ("unobservable: a conflict only after the original task", "come after the original task's first step"),
    ("truncated original: a subgoal dropped", "drops the base task's subgoal"),
    ("a step claimed original that adds nothing to the task", "marked original but achieves nothing"),
    ("a step claimed original that adds nothing to the task", "does not pick up"),
    ("a step does not name its goal's entities (a replaced object or destination)", "which its goal"),
    ("ambiguous reference: a pronoun or a shared name in a constraint", "pronoun"),
    ("ambiguous reference: a pronoun or a shared name in a constraint", "unambiguously"),
    ("ambiguous reference: a pronoun or a shared name in a constraint", "does not name"),
    ("instruction: satisfiable by some order of execution", "satisfiable"),
    ("instruction: a constraint on something the step need not touch or move", "need not"),
    ("instruction: a constraint that does not contradict its goal", "do not contradict"),
    ("instruction: picking up without grasping (a bowl can be scooped)", "ungrasped"),
    ("instruction: a constraint on a goal the step does not ask for", "is not what step"),
    ("grounding: a landmark, not the object, destination or receptacle", "role"),
    ("grounding: referent not absent (a synonym, part or kind of something present)", "not absent"),
    ("spatial: false by less than a camera shows (< 6 cm or the subject's radius)", "false by only"),
    ("spatial: an earlier step moves the relation's entities", "earlier step"),
    ("spatial: a landmark its own step moves", "which that same step"),
    ("spatial: a bare relation a motion verb turns into a destination", "not a relative clause"),
    ("spatial: a landmark that could mean either of two twins", "could mean"),
    ("spatial: a claim about a twinned bowl (its clause attaches to the landmark)", "twinned object"),
    ("spatial: a drawer's hidden contents", "inside a closed drawer"),
    ("spatial: a direction against a fixture that faces its own way", "faces its own way"),
    ("spatial: 'next to' between two things of one kind", "two things of one kind"),
    ("spatial: the relation holds in a paired state", "holds in initial state"),
    ("physical: a violation the table does not plainly deny", "does not plainly lack"),
    ("physical: an added participant the goal can be met without (never reached)", "added participant"),
    ("physical: an added participant the goal can be met without (never reached)", "adds a participant"),
    ("physical: support, pouring or containment in what may open (disputable)", "is disputable"),
    ("physical: support, pouring or containment in what may open (disputable)", "invites opening"),
    ("physical: the same object grasped twice", "grasps"),
    ("physical: fewer than four kinds of violation in a level cell", "need 4"),
    ("physical: one skeleton over a quarter of its cell", "skeleton"),
    ("same text twice within a LIBERO suite", "same instruction as"),
    ("same text twice within a LIBERO suite", "same text as"),
]
FORMAT_ONLY = ("needs its margin_m in the witness",)
"""Reasons about a 2.0 witness field the 1.x file cannot have; the rule behind it is counted on its own."""
KIND_OF_NEED = {  # 1.x physical witnesses name the affordance; 2.0 also names the kind of violation
    "graspable": "fixed",
    "movable": "fixed",
    "container": "containment",
    "support": "support",
    "fits_in": "size",
    "openable": "articulation",
    "turnable": "switch",
    "foldable": "rigidity",
    "pourable": "pouring",
}


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
    if case.family == "instruction":  # 1.x pairs claim no mode: take the stronger one
        witness["conflicts"] = [[*pair[:2], "simultaneous"] for pair in witness.get("conflicts", [])]
    if case.family == "physical":
        for v in witness.get("violations", []):
            v.setdefault("kind", KIND_OF_NEED.get(v.get("needs"), "unknown"))
    if case.family == "grounding":
        for r in witness.get("referents", []):
            r.setdefault("source", "out_of_domain")  # 1.x drew every referent from the out-of-domain list
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
        if any(needle in reason for needle in FORMAT_ONLY):
            continue
        rejected.add(case_id)
        label = next((label for label, needle in RULES if needle in reason), "other: " + reason[:90])
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
