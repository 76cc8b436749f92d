"""The instruction family's rules: every claimed pair of requirements contradicts under EVERY order.

A case's witness lists ``requirements`` (id, step, text, literal; see
:mod:`conflictbench.tasks.operators.contradictions`) and ``conflicts`` as ``[id_a, id_b, mode]``.
Rules:

- every literal is well formed, its text is in the instruction, and every entity it names is in
  the scene and named by its text;
- a goal literal (``goal``/``do``) is what its step asks for (one of the step's goals, or lifting
  the object the step picks up);
- a constraint (``keep``/``end``/``avoid``) names each entity by a phrase that denotes it alone in
  the scene, never by a pronoun;
- each pair contradicts (:func:`~conflictbench.tasks.operators.contradictions.explain`), and its
  mode is the one the rule gives (``simultaneous`` or ``final_states``); a pair that an order of
  execution satisfies ("do it, then undo it") is rejected with that reason;
- no "untouched" constraint on a pushing step (push, slide, shove, move ... aside / out of the way
  / to one side, "move X onto Y", close or shut): the thing can be pushed with another held object;
- no filler: no two pairs share a constraint literal in one step, and in L2 every pair sets a constraint
  against the one step's own goal, so each factor alone contradicts it.
"""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.operators.contradictions import HEADS, MODES, explain, literal_entities, why_not
from conflictbench.tasks.operators.frames import aux_steps
from conflictbench.tasks.operators.instruction import denotes_only
from conflictbench.tasks.scene.task_model import TaskModel

from .structure import PRONOUN
from .text import _named_or_pronoun, names_in, normalise

GOAL_HEADS = ("goal", "do")
PUSH_VERBS = ("push", "slide", "shove", "move", "close", "shut")
"""Step verbs a held object can do by pushing: "untouched" does not contradict them."""


def _added_goals(model: TaskModel) -> list[tuple[str, ...]]:
    return [slot.step.goal[0] for slot in aux_steps(model)]


def _unique_name(model: TaskModel, entity: str, text: str) -> bool:
    """Does the text name the entity by a phrase that denotes nothing else in the scene?"""
    return any(names_in(text, [n]) and denotes_only(model, n, entity) for n in model.entity_names(entity) if n)


def _requirement_problems(r: dict, case: ConflictCase, model: TaskModel) -> list[str]:
    rid, lit, text = r.get("id"), r.get("literal"), r.get("text", "")
    if not isinstance(lit, list) or len(lit) < 3 or lit[0] not in HEADS:
        return [f"requirement {rid}: malformed literal {lit!r}"]
    return [
        *_wording_problems(rid, lit, text, case, r.get("step")),
        *_entity_problems(rid, lit, text, case, model),
        *_goal_problems(rid, lit, case, model, r.get("step")),
    ]


def _wording_problems(rid, lit: list, text: str, case: ConflictCase, step: object) -> list[str]:
    """The requirement's text: in the instruction, naming a constraint's entity in full and the robot where the
    literal is about it, and no "untouched" on a step that pushing with a held object does."""
    out = []
    if not text or text not in case.instruction:
        out.append(f"requirement {rid}: text {text!r} is not in the instruction")
    if lit[0] not in GOAL_HEADS and PRONOUN.search(normalise(text)):
        out.append(f"requirement {rid}: the constraint {text!r} uses a pronoun; name the entity in full")
    if "robot" in lit[2:] and not names_in(text, {"robot", "arm", "robot arm"}):
        out.append(f"requirement {rid}: its text does not name the robot arm")
    body = _step_body(case, step)
    if lit[:2] == ["keep", "untouched"] and body.startswith(tuple(v + " " for v in PUSH_VERBS)):
        out.append(f"requirement {rid}: 'untouched' on a pushing step ({body!r}) is met by pushing with a held object")
    return out


def _entity_problems(rid, lit: list, text: str, case: ConflictCase, model: TaskModel) -> list[str]:
    """Every entity of the literal is in the scene and named by the text (a constraint's by a unique name)."""
    out = []
    for e in literal_entities(lit):
        if e not in model.facts.entities and e not in model.problem.fixtures:
            out.append(f"requirement {rid}: {e!r} is not in the scene")
        elif not _named_or_pronoun(model, e, text, case.instruction):
            out.append(f"requirement {rid}: its text does not name {e}")
        elif lit[0] not in GOAL_HEADS and not _unique_name(model, e, text):
            out.append(f"requirement {rid}: {text!r} does not name {e} unambiguously (another thing shares the name)")
    return out


def _goal_problems(rid, lit: list, case: ConflictCase, model: TaskModel, step: object) -> list[str]:
    """A goal literal is what its step asks for; lifting is of the object the step picks up."""
    out = []
    goals, entities = case.witness.get("step_goals", []), case.witness.get("step_entities", [])
    if lit[0] == "goal" and isinstance(step, int) and 1 <= step <= len(goals):
        asked = [list(g) for g in goals[step - 1]]
        roles = case.witness.get("step_roles", [])
        if step <= len(roles) and roles[step - 1] == "added" and step <= len(entities):
            # an added step achieves no base subgoal: its goal is the one the scene offers for it
            asked += [list(a) for a in _added_goals(model) if a[1] in entities[step - 1]]
        if lit[1:] not in asked:
            out.append(f"requirement {rid}: goal {lit[1:]} is not what step {step} asks for")
    if lit[:2] == ["do", "lift"] and isinstance(step, int) and 1 <= step <= len(entities):
        if lit[2] not in entities[step - 1]:
            out.append(f"requirement {rid}: step {step} does not pick up {lit[2]}")
    return out


def _step_body(case: ConflictCase, step: object) -> str:
    steps = case.witness.get("steps", [])
    return normalise(steps[step - 1]) if isinstance(step, int) and 1 <= step <= len(steps) else ""


def check_contradiction(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    w, out = case.witness, []
    reqs = {r.get("id"): r for r in w.get("requirements", []) if isinstance(r, dict)}
    for r in reqs.values():
        out += _requirement_problems(r, case, model)
    if not w.get("conflicts"):
        out.append("the witness lists no contradicting requirements")
    seen_constraints: list = []
    for pair in w.get("conflicts", []):
        out += _conflict_problems(pair, reqs, case, model, states, seen_constraints)
    return out


def _conflict_problems(pair, reqs: dict, case: ConflictCase, model, states: frozenset, seen: list) -> list[str]:
    """One claimed conflict: two listed requirements that contradict in the mode it says, and no filler."""
    if not (isinstance(pair, list) and len(pair) in (2, 3) and all(p in reqs for p in pair[:2])):
        return [f"conflict {pair!r} does not name two listed requirements"]
    a, b = (reqs[p].get("literal") for p in pair[:2])
    if not (isinstance(a, list) and isinstance(b, list) and len(a) >= 3 and len(b) >= 3):
        return []  # reported as malformed by _requirement_problems
    return [*_contradiction_problems(pair, a, b, model, states), *_filler_problems(pair, reqs, a, b, case, seen)]


def _contradiction_problems(pair: list, a: list, b: list, model: TaskModel, states: frozenset) -> list[str]:
    """The two literals contradict under every order, in the mode the pair says."""
    out = []
    mode = pair[2] if len(pair) == 3 else None
    if mode not in MODES:
        out.append(f"conflict {pair!r} must say its mode ({' or '.join(MODES)})")
    found = explain(a, b, model.facts, states)
    if found is None:
        why = why_not(a, b, model.facts, states)
        out.append(f"requirements {pair[0]} and {pair[1]} do not contradict ({a} / {b}): {why}")
    elif mode in MODES and found[0] != mode:
        out.append(f"conflict {pair[:2]} is {found[0]}, not {mode} ({found[1]})")
    return out


def _filler_problems(pair: list, reqs: dict, a: list, b: list, case: ConflictCase, seen: list) -> list[str]:
    """No constraint of an earlier pair (``seen``, extended here) again in its step, and in L2 each pair sets
    one constraint against the step's own goal."""
    out = []
    constraints = [(reqs[p].get("step"), lit) for p, lit in zip(pair[:2], (a, b)) if lit[0] not in GOAL_HEADS]
    for scoped in constraints:
        if scoped in seen:
            out.append(f"conflict {pair[:2]} repeats the constraint {scoped[1]} in step {scoped[0]}: no filler")
        seen.append(scoped)
    if case.level == "L2" and len(constraints) != 1:
        out.append(f"conflict {pair[:2]}: in L2 each factor is a constraint against the step's own goal")
    return out
