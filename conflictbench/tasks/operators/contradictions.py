"""Requirements as literals, and the rules that make two of them contradict under EVERY order.

An instruction-family witness lists the instruction's requirements as literals::

    ["goal", pred, *args]     what a step asks to bring about (on, in, open, close, turnon,
                              turnoff, moved): an action, so "then undo it" is one way to meet it
    ["do", "lift", e]         the robot picks e up (the "pick up" half of a split step)
    ["end", pred, *args]      stated as an end condition: pred holds when the robot finishes
    ["avoid", pred, *args]    stated as an end condition: pred does not hold when the robot finishes
    ["keep", pred, e]         pred (open, close, turnon, turnoff) holds the whole time
    ["keep", "still", e]      e never moves; e may be "robot" (the robot arm stays still)
    ["keep", "untouched", e]  the robot never touches e

and names its contradicting pairs as ``[id_a, id_b, mode]``. A pair contradicts only when NO order
of execution meets both; its mode says why:

- ``simultaneous``: one requirement holds throughout the step (keep ...) while the other needs
  the opposite at some moment: a goal that must change e vs. keeping e still or untouched (e is
  the step's own moved object or operated drawer, door or stove, never a holder such as the
  drawer's cabinet: the handle belongs to both); any change vs. a still robot arm; a goal state
  vs. keeping the opposite state; keeping a state vs. an end condition that denies it.
- ``final_states``: two end conditions that no single final state meets (end p vs. avoid p,
  end open vs. end close of one thing).

Never contradictions, and :func:`why_not` says so: a step's goal vs. an end condition that undoes
it ("put the bowl on the stove ... make sure the bowl is not on the stove at the end": do it, then
undo it); a constraint on something the goal need not touch or move; "pick up e without grasping
e" (a bowl can be scooped). Assumption, stated once: the robot changes the world only through its
own contact (it moves what it touches; nothing moves on its own).
"""

from __future__ import annotations

from conflictbench.tasks.scene.facts import TaskFacts

EXCLUSIVE = {"open": "close", "close": "open", "turnon": "turnoff", "turnoff": "turnon"}
STATE_PREDICATES = tuple(EXCLUSIVE)
RELOCATING = ("on", "in", "moved")
MODES = ("simultaneous", "final_states")
HEADS = ("goal", "do", "end", "avoid", "keep")
KEEPS = ("still", "untouched", *STATE_PREDICATES)


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


def _is_region(facts: TaskFacts, entity: str) -> bool:
    e = facts.entities.get(entity)
    return e is not None and e.kind == "region"


def _moved(facts: TaskFacts, lit: list) -> set[str]:
    """What the literal's change moves: the relocated object, or an opened/closed drawer (a region
    that opens is a drawer, which slides). A microwave's body does not move when its door does."""
    if lit[:2] == ["do", "lift"] or lit[1] in RELOCATING:
        return {lit[2]}
    if lit[1] in ("open", "close") and _is_region(facts, lit[2]):
        return {lit[2]}
    return set()


def _touched(lit: list) -> set[str]:
    """What the robot must touch for the literal's change: the moved or operated thing itself."""
    if lit[:2] == ["do", "lift"] or lit[1] in RELOCATING or lit[1] in STATE_PREDICATES:
        return {lit[2]}
    return set()


def _show(lit: list) -> str:
    return f"{lit[1]}({', '.join(lit[2:])})"


def explain(a: list, b: list, facts: TaskFacts, states: frozenset) -> tuple[str, str] | None:
    """``(mode, why)`` when no order of execution meets both requirements, else ``None``."""
    for x, y in ((a, b), (b, a)):
        found = _one_way(x, y, facts, states)
        if found:
            return found
    return None


def contradiction(a: list, b: list, facts: TaskFacts, states: frozenset) -> str | None:
    """Why requirements ``a`` and ``b`` cannot both be met, or ``None``."""
    found = explain(a, b, facts, states)
    return found[1] if found else None


def _one_way(x: list, y: list, facts: TaskFacts, states: frozenset) -> tuple[str, str] | None:
    return _end_conflict(x, y) or _change_conflict(x, y, facts, states)


def _end_conflict(x: list, y: list) -> tuple[str, str] | None:
    """``x`` and ``y`` say opposite things about the end (or ``x`` holds throughout what ``y`` forbids at the
    end): contradictory whatever the scene."""
    if x[0] == "end" and y[0] == "avoid" and x[1:] == y[1:]:
        return "final_states", f"{_show(x)} must hold at the end and must not"
    if x[0] == y[0] == "end" and x[1] in EXCLUSIVE and y[1] == EXCLUSIVE[x[1]] and x[2:] == y[2:]:
        return "final_states", f"{x[2]} cannot end both {x[1]} and {y[1]}"
    if x[0] == "keep" and x[1] in STATE_PREDICATES:
        if (y[0] == "avoid" and y[1:] == x[1:]) or (y[0] == "end" and y[1] == EXCLUSIVE[x[1]] and y[2:] == x[2:]):
            return "simultaneous", f"{_show(x)} must hold throughout, so also at the end, where it must not"
    return None


def _change_conflict(x: list, y: list, facts: TaskFacts, states: frozenset) -> tuple[str, str] | None:
    """``x`` changes the scene in every state, in a way that ``y``'s keeping forbids while it happens."""
    if not _changes(facts, x, states) or y[0] != "keep":
        return None
    if y[1] in STATE_PREDICATES and x[0] == "goal" and EXCLUSIVE.get(x[1]) == y[1] and x[2:] == y[2:]:
        return "simultaneous", f"{x[2]} must become {x[1]} while staying {y[1]} the whole time"
    if y[1] == "still" and y[2] == "robot":
        return "simultaneous", f"{_show(x)} needs the robot arm to move, and it must stay still"
    if y[1] == "still" and y[2] in _moved(facts, x):
        return "simultaneous", f"{_show(x)} moves {y[2]}, which must not move"
    if y[1] == "untouched" and y[2] in _touched(x):
        return "simultaneous", f"{_show(x)} cannot be done without touching {y[2]}"
    return None


def why_not(a: list, b: list, facts: TaskFacts, states: frozenset) -> str:
    """Why a claimed pair is NOT a contradiction (call it when :func:`explain` found none)."""
    for x, y in ((a, b), (b, a)):
        if x[0] == "goal" and y[0] == "avoid" and x[1:] == y[1:]:
            return f"satisfiable by doing {_show(x)}, then undoing it: the end condition comes after the step"
        if x[0] == "goal" and y[0] == "end" and EXCLUSIVE.get(x[1]) == y[1] and x[2:] == y[2:]:
            return f"satisfiable by doing {_show(x)}, then undoing it: the end condition comes after the step"
        if x[0] == "goal" and already(facts, x, states):
            return f"{_show(x)} already holds in some initial state, so nothing need change"
        if y[:2] == ["keep", "ungrasped"]:
            return "an object can be picked up without closing the gripper on it (scooped, hooked)"
        if y[0] == "keep" and y[1] in ("still", "untouched") and y[2] != "robot" and x[0] in ("goal", "do"):
            if y[2] not in _touched(x):
                return (
                    f"{_show(x)} need not touch or move {y[2]}: only the step's own moved object, "
                    "the operated drawer, door or stove itself, or the robot arm makes a contradiction"
                )
    return "no rule explains why both cannot be met"


def literal_entities(lit: list) -> list[str]:
    """Scene entities the literal names (the robot is not a scene entity)."""
    return [e for e in lit[2:] if e != "robot"]
