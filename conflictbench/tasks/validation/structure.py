"""Rules every case meets whatever its family: steps, levels, an observable conflict, the whole
original task, and unambiguous pronouns.

The witness describes the instruction's steps: ``steps`` (each step's text, in order), and, per
step, ``step_roles`` (``original``: a step of the base task, or part of one, such as one object of
a two-object placing; ``added``: a plausible extra step) and ``step_goals`` (the base task's goal
literals the step achieves). The rules re-derive what they can from the base task:

- **Whole original**: the steps' goals are exactly the base task's subgoals, and every step names
  the entities of its goals (or the factor that stands in for one, a grounding referent).
- **Observable**: an episode ends as soon as the ORIGINAL goal holds, so a conflict placed after the
  original steps would never be reached. Added steps come before every original step.
- **Unambiguous**: a pronoun is only the object of a placing verb whose antecedent is the object
  just picked up ("pick up the bowl and put it on the plate"); constraints never use pronouns.
- **A step is a manipulation with its own goal** (suite 2.1): a "pick up X" step before "put it on
  the plate" is half of one manipulation, not a step; a single-step level's one step achieves ONE
  goal literal (a base task of two, "put both X and Y in the basket", is L3/L4 material only); L4's
  factors are two distinct ones in different steps (:mod:`.factors`).
- **Added steps claim nothing false**: "move X out of the way" (or aside, to one side) only where X
  stands near what the task touches (:meth:`TaskModel.in_the_way`).
"""

from __future__ import annotations

import re

from conflictbench.core import ConflictCase
from conflictbench.tasks.scene.task_model import TaskModel

from .factors import FAMILY_FACTORS, check_factors
from .text import names_in, normalise

ROLES = ("original", "added")
IN_THE_WAY_CLAIM = re.compile(r"\b(out of the way|aside|to one side|out of its way)\b")
"""Wordings of an added step that say the thing it moves is in the way."""
PRONOUN = re.compile(r"\b(it|them|its|they|itself)\b")
PLACING = ("place", "put", "set", "drop", "stow", "carry", "move", "slide", "bring", "lay", "stand")
"""Verbs whose object may be the pronoun for the thing just picked up: "... and place it on the plate"."""
INTERVENING = {"with", "inside", "tucked", "packed", "together", "while"}
"""Words between a pick-up and "put it" that bring in a second thing "it" could mean."""
GRASPING = ("pick up", "grab", "lift", "take", "hold", "fold", "crumple", "squash", "bend", "open", "roll up", "crush")
"""Verbs that introduce the antecedent of a following placing verb's pronoun."""


def _steps_and_level(case: ConflictCase, wtype: str) -> list[str]:
    w = case.witness
    steps = w.get("steps")
    if not isinstance(steps, list) or not steps or not all(isinstance(s, str) and s for s in steps):
        return ["witness field 'steps' must list the instruction's steps"]
    out = _steps_in_order(case.instruction, steps)
    factors = w.get(FAMILY_FACTORS.get(wtype, "factors"), [])
    if not isinstance(factors, list) or not factors:
        return out + [f"witness field {FAMILY_FACTORS.get(wtype, 'factors')!r} is empty"]
    factor_steps = _factor_steps(w, wtype, factors)
    if not all(isinstance(s, int) and 1 <= s <= len(steps) for s in factor_steps):
        out.append(f"factor steps {factor_steps} do not point at the {len(steps)} step(s)")
    n, k, spread = len(steps), len(factors), len(set(factor_steps))
    expected = {
        "L1": n == 1 and k == 1,
        "L2": n == 1 and k >= 2,
        "L3": n >= 2 and k == 1,
        "L4": n >= 2 and k >= 2 and spread >= 2,
    }
    if not expected.get(case.level, False):
        out.append(f"level {case.level} does not match the witness ({n} step(s), {k} factor(s) in {spread} step(s))")
    return out


def _steps_in_order(instruction: str, steps: list[str]) -> list[str]:
    """Every step's text is in the instruction, each after the one before (the first missing one reported)."""
    pos = 0
    for s in steps:
        i = instruction.find(s, pos)
        if i < 0:
            return [f"step {s!r} is not in the instruction (in order)"]
        pos = i + len(s)
    return []


def _factor_steps(w: dict, wtype: str, factors: list) -> list:
    """The step of each factor: a contradiction's is the later of its two requirements' steps."""
    if wtype == "contradiction":
        step_of = {r.get("id"): r.get("step") for r in w.get("requirements", []) if isinstance(r, dict)}
        return [max(step_of.get(p, 0) or 0 for p in pair) if isinstance(pair, list) else 0 for pair in factors]
    return [f.get("step") if isinstance(f, dict) else None for f in factors]


def check_structure(case: ConflictCase, wtype: str, model: TaskModel) -> list[str]:
    out = _steps_and_level(case, wtype)
    if out:
        return out
    out += check_factors(case.level, case.witness, wtype)
    out += _one_manipulation(case) + _added_claims(case, model)
    return out + _observable_and_whole(case, wtype, model) + _pronouns(case)


def _one_manipulation(case: ConflictCase) -> list[str]:
    """Each step has its own goal; a single-step level's step has exactly one."""
    w, out = case.witness, []
    goals, roles = w.get("step_goals") or [], w.get("step_roles") or []
    if case.level in ("L1", "L2") and goals and isinstance(goals[0], list) and len(goals[0]) > 1:
        out.append(
            f"a single-step level on a base task of {len(goals[0])} manipulations ({goals[0]}): use it for L3/L4"
        )
    for i, (role, literals) in enumerate(zip(roles, goals)):
        if role == "original" and not literals:
            out.append(
                f"step {i + 1} has no goal of its own: reaching for an object and placing it is one step, not two"
            )
    return out


def _added_claims(case: ConflictCase, model: TaskModel) -> list[str]:
    """An added step that says it moves a thing "out of the way" must be true of the scene."""
    w, out = case.witness, []
    states = frozenset(case.init_states) if case.init_states else None
    said = w.get("step_entities") or []
    for i, (role, text) in enumerate(zip(w.get("step_roles") or [], w.get("steps") or [])):
        if role != "added" or not IN_THE_WAY_CLAIM.search(text):
            continue
        moved = [e for e in (said[i] if i < len(said) else []) if e in model.facts.entities]
        far = [e for e in moved if not model.in_the_way(e, states)]
        if far:
            out.append(
                f"step {i + 1} ({text!r}) claims {', '.join(far)} is in the way, but it stands apart from "
                "what the task touches in some initial state"
            )
    return out


def _atom(literal) -> tuple[str, ...]:
    return tuple(str(a) for a in literal)


def _replaced(case: ConflictCase, wtype: str) -> dict[int, set[str]]:
    """Step number -> entities a grounding factor stands in for (the text names the referent instead)."""
    out: dict[int, set[str]] = {}
    if wtype == "absent_referent":
        for r in case.witness.get("referents", []):
            if isinstance(r, dict) and r.get("replaces"):
                out.setdefault(int(r.get("step", 0)), set()).add(str(r["replaces"]))
    return out


def _observable_and_whole(case: ConflictCase, wtype: str, model: TaskModel) -> list[str]:
    w = case.witness
    steps = w["steps"]
    roles, goals = w.get("step_roles"), w.get("step_goals")
    if not (isinstance(roles, list) and len(roles) == len(steps) and all(r in ROLES for r in roles)):
        return [f"witness field 'step_roles' must give each of the {len(steps)} step(s) a role ({' or '.join(ROLES)})"]
    if not (isinstance(goals, list) and len(goals) == len(steps) and all(isinstance(g, list) for g in goals)):
        return [f"witness field 'step_goals' must list each of the {len(steps)} step(s)' goal literals"]
    out = _late_added_steps(roles)
    base = {_atom(a) for s in model.steps for a in s.goal}
    asked: set[tuple[str, ...]] = set()
    replaced = _replaced(case, wtype)
    out += _entities_named(case, model, replaced)
    for i, (role, literals) in enumerate(zip(roles, goals)):
        if role == "added" and literals:
            out.append(f"step {i + 1} is marked added but achieves the base task's goal {literals}")
        for literal in literals:
            atom = _atom(literal)
            if atom not in base:
                out.append(f"step {i + 1}: {list(atom)} is not a subgoal of the base task")
                continue
            asked.add(atom)
            out += _goal_named(i, atom, steps, replaced, model)
    missing = sorted(base - asked)
    if missing:
        out.append(f"the instruction drops the base task's subgoal(s) {[list(m) for m in missing]}")
    return out


def _late_added_steps(roles: list[str]) -> list[str]:
    """Added steps must come before the original task's first: once its goal is met the episode can end."""
    first_original = roles.index("original") if "original" in roles else len(roles)
    late = [i + 1 for i, r in enumerate(roles) if r == "added" and i > first_original]
    if late:
        return [
            f"added step(s) {late} come after the original task's first step: the episode can end "
            "(original goal met) before the conflict is reached"
        ]
    return []


def _goal_named(i: int, atom: tuple[str, ...], steps: list[str], replaced: dict[int, set[str]], model) -> list[str]:
    """Step ``i + 1`` names every entity of its goal ``atom`` (or the step before does, for "put it ...";
    or a grounding referent stands in for it)."""
    out = []
    text, stand_ins = steps[i], replaced.get(i + 1, set())
    if i > 0 and PRONOUN.search(text):
        text = steps[i - 1] + " " + text  # "pick up the bowl, then put it on the plate"
        stand_ins = stand_ins | replaced.get(i, set())  # "pick up the banana, then put it ..."
    for entity in atom[1:]:
        if entity in stand_ins:
            continue
        if not names_in(text, model.entity_names(entity) | model.entity_names(model.parent(entity))):
            out.append(f"step {i + 1} does not name {entity}, which its goal {list(atom)} needs")
    return out


def _entities_named(case: ConflictCase, model: TaskModel, replaced: dict[int, set[str]]) -> list[str]:
    """What the witness says each step acts on, the step's text names (or the step before, for "put
    it ..."; or a grounding referent stands in for it): other rules trust ``step_entities``."""
    w, out = case.witness, []
    steps, said = w["steps"], w.get("step_entities")
    if said is None:
        return []
    if not (isinstance(said, list) and len(said) == len(steps)):
        return [f"witness field 'step_entities' must list each of the {len(steps)} step(s)' entities"]
    for i, entities in enumerate(said):
        text = steps[i] if i == 0 else f"{steps[i - 1]} {steps[i]}"  # "pick up X, then put it ..."
        stand_ins = replaced.get(i + 1, set()) | replaced.get(i, set())
        stand_ins |= {model.parent(x) for x in stand_ins}  # "open the backpack": for the drawer and its cabinet
        for e in entities if isinstance(entities, list) else []:
            if e in stand_ins or e not in model.facts.entities and e not in model.problem.fixtures:
                continue
            if not names_in(text, model.entity_names(e) | model.entity_names(model.parent(e))):
                out.append(f"step {i + 1} is said to act on {e}, which it does not name")
    return out


def _pronouns(case: ConflictCase) -> list[str]:
    """A pronoun may only be the object of a placing verb whose one antecedent a grasping verb just
    introduced: in the same step with nothing else said between them ("pick up X and put it ..."), or
    as the second step right after a plain pick-up of the first ("pick up X, then put it ...")."""
    out = []
    bodies = [normalise(s) for s in case.witness["steps"]]
    in_bodies = sum(len(PRONOUN.findall(b)) for b in bodies)
    if len(PRONOUN.findall(normalise(case.instruction))) > in_bodies:
        out.append("a pronoun in a constraint: it could mean several things (name the entity)")
    for i, body in enumerate(bodies):
        for match in PRONOUN.finditer(body):
            problem = _pronoun_problem(match.group(1), body[: match.start()].split(), bodies[i - 1] if i > 0 else "", i)
            if problem:
                out.append(problem)
    return out


def _pronoun_problem(word: str, before: list[str], earlier: str, i: int) -> str | None:
    """What is wrong with pronoun ``word`` after the words ``before`` it in step ``i + 1`` (``earlier``: the
    step before's text), if anything."""
    if word in ("its", "they", "itself") or (before and before[-1] not in PLACING):
        return f"pronoun {word!r} at {' '.join(before[-4:])!r}: only 'place it' after a pick-up"
    if len(before) > 1:  # within the step: "pick up X and put it", nothing in between
        grasp = max((m.end() for g in GRASPING for m in re.finditer(rf"\b{g}\b", " ".join(before))), default=-1)
        between = " ".join(before)[grasp:] if grasp >= 0 else ""
        if grasp < 0:
            return f"pronoun {word!r} has no object picked up just before it"
        if set(between.split()) & INTERVENING:
            return f"pronoun {word!r} follows {between.strip()!r}: two things could be meant"
        return None
    if not any(re.search(rf"\b{g}\b", earlier) for g in GRASPING):
        return f"pronoun {word!r} has no object picked up just before it"
    if i != 1 or PRONOUN.search(earlier) or set(earlier.split()) & (set(PLACING) | INTERVENING):
        # "lift the stove, then fold the bottle, then place it": the stove or the bottle?
        return f"pronoun {word!r} opens a step after others that handled something: name it"
    return None
