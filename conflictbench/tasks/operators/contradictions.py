"""Requirements as literals, and the rules that make two of them contradictory.

An instruction-family witness lists the instruction's requirements as literals::

    ["goal", pred, *args]     the final state must satisfy pred (on, in, open, close, turnon, turnoff, moved)
    ["avoid", pred, *args]    the final state must not satisfy it
    ["keep", pred, *args]     pred holds throughout (open, close, turnon, turnoff)
    ["keep", "still", e]      e never moves (e may be "robot": the arm stays still)
    ["keep", "untouched", e]  the robot never touches e
    ["keep", "ungrasped", e]  the gripper never closes on e
    ["do", "lift", e]         the robot picks e up

and which pairs contradict. :func:`contradiction` re-derives every claimed pair from the rules
below and the scene facts; a pair no rule explains is not a contradiction. Assumption, stated once:
the robot changes the world only through its own contact (it moves what it touches, and nothing
else moves on its own), so a goal that must change something cannot be met by a robot that stays
still or never touches that thing.
"""

from __future__ import annotations

from conflictbench.tasks.scene.facts import TaskFacts

EXCLUSIVE = {"open": "close", "close": "open", "turnon": "turnoff", "turnoff": "turnon"}
STATE_PREDICATES = tuple(EXCLUSIVE)
RELOCATING = ("on", "in", "moved")


def _parent(facts: TaskFacts, entity: str) -> str:
    e = facts.entities.get(entity)
    return e.parent if e is not None and e.kind == "region" and e.parent else entity


def already(facts: TaskFacts, literal: list, states: frozenset) -> bool:
    """Does the goal literal already hold in some paired initial state (then nothing needs to change)?

    A goal means what LIBERO's success check means by it, so this asks LIBERO's own predicate (a
    bowl touching the plate's rim is not yet "on the plate").
    """
    pred, args = literal[1], literal[2:]
    if pred in ("on", "in", *STATE_PREDICATES):
        return bool(facts.predicate(pred, *args) & states)
    return False  # "moved" is never true at the start


def _changes(facts: TaskFacts, lit: list, states: frozenset) -> bool:
    return (lit[0] == "goal" and not already(facts, lit, states)) or lit[:2] == ["do", "lift"]


def _touched(facts: TaskFacts, lit: list) -> set[str]:
    """Entities the robot must touch to satisfy the literal."""
    if lit[:2] == ["do", "lift"]:
        return {lit[2]}
    if lit[0] != "goal":
        return set()
    if lit[1] in RELOCATING:
        return {lit[2]}
    if lit[1] in STATE_PREDICATES:
        return {lit[2], _parent(facts, lit[2])}
    return set()


def contradiction(a: list, b: list, facts: TaskFacts, states: frozenset) -> str | None:
    """Why requirements ``a`` and ``b`` cannot both be met, or ``None``."""
    for x, y in ((a, b), (b, a)):
        reason = _one_way(x, y, facts, states)
        if reason:
            return reason
    return None


def _one_way(x: list, y: list, facts: TaskFacts, states: frozenset) -> str | None:
    if x[0] == "goal" and y[0] == "avoid" and x[1:] == y[1:]:
        return f"{x[1]}{tuple(x[2:])} must hold at the end and must not"
    if x[0] == "keep" and y[0] == "avoid" and x[1] in STATE_PREDICATES and x[1:] == y[1:]:
        return f"{x[1]}{tuple(x[2:])} must hold throughout yet not at the end"
    if x[0] == "goal" and y[0] in ("goal", "keep") and x[1] in EXCLUSIVE and y[1] == EXCLUSIVE[x[1]] and x[2:] == y[2:]:
        return f"{x[2]} cannot end both {x[1]} and {y[1]}"
    if y[:2] == ["keep", "still"]:
        if y[2] == "robot" and _changes(facts, x, states):
            return f"{x[1:]} needs the robot to move, which must stay still"
        if _changes(facts, x, states) and (x[1] in RELOCATING or x[:2] == ["do", "lift"]) and x[2] == y[2]:
            return f"{x[2]} must be moved and must not move"
    if y[:2] == ["keep", "untouched"] and _changes(facts, x, states) and y[2] in _touched(facts, x):
        return f"{x[1:]} cannot be done without touching {y[2]}"
    if y[:2] == ["keep", "ungrasped"] and x[:2] == ["do", "lift"] and x[2] == y[2]:
        return f"{x[2]} must be picked up without being grasped"
    return None


def literal_entities(lit: list) -> list[str]:
    if lit[:2] in (["keep", "still"], ["keep", "untouched"], ["keep", "ungrasped"], ["do", "lift"]):
        return [lit[2]] if lit[2] != "robot" else []
    return list(lit[2:])
