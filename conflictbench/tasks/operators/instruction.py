"""Instruction operators: requirements inside the text that no order of execution can all meet.

Rules (suite 2.0), each enforced again by :mod:`conflictbench.tasks.validation.instruction`:

- Every contradiction is SIMULTANEOUS: a constraint that holds throughout a step against the
  step's own goal. Per step kind:

  * moving steps (place, push, move aside): keep the moved object still, never touch
    the moved object, or keep the robot arm still, except:
  * pushing steps (push, slide, shove, move aside), "move X onto Y" and closing a drawer or door:
    never "untouched", since the thing can be pushed with another held object; a place step constrained "untouched" is
    written with a carrying verb (put, place, pick up ... and put), never "move";
  * state steps (open, close, turn on): keep the operated drawer, door or stove in the opposite
    state the whole time, never touch the operated thing itself, or keep the robot arm still.

  No end conditions against a step ("turn the stove on and make sure it is off at the end" is met
  by doing it, then undoing it), no "pick up X without grasping X" (X can be scooped), and no
  constraint on anything but the step's own moved or operated thing or the robot arm ("open the
  drawer without touching the cabinet" is met through the handle, which is both).
- A constraint names its entity in full or by a shorter name that denotes it alone in the scene;
  never a pronoun ("... put them in the basket without touching it" could mean the basket).
- L1/L3: one constraint on one step (L3: any step of the frame; added steps come first, so every
  step is reached before the episode can end). L2: two constraints of different kinds on the one
  step, each alone contradicting its goal. L4: constraints on at least two different steps.
- Several phrasings per constraint kind, chosen with the rng, so instructions do not repeat.

The witness lists every requirement as a literal (:mod:`.contradictions`) and the pairs that
contradict as ``[goal id, constraint id, "simultaneous"]``.
"""

from __future__ import annotations

import itertools
import random
from dataclasses import dataclass

from conflictbench.tasks.scene.affordances import category, load_table
from conflictbench.tasks.scene.lexicon import words as _words
from conflictbench.tasks.scene.task_model import TaskModel
from conflictbench.tasks.validation.factors import distinct_spread, factors_of

from .contradictions import EXCLUSIVE, already
from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose, frames_for

# Each kind: (phrases that attach to the step, phrases that stand as a second imperative).
# Phrases never contain "it": a constraint names its entity.
STILL = (
    ("without moving {x}", "while keeping {x} fixed in place", "without letting {x} move at all"),
    ("do not move {x} at all", "keep {x} fixed in place the whole time", "make sure {x} never moves"),
)
UNTOUCHED = (
    ("without touching {x}", "without making any contact with {x}", "without the robot ever touching {x}"),
    ("never touch {x}", "do not touch {x} at any point", "make no contact with {x} at all"),
)
ROBOT = (
    (
        "without moving the robot arm",
        "while keeping the robot arm completely still",
        "without the robot arm moving at all",
    ),
    ("keep the robot arm completely still", "do not move the robot arm at all", "make sure the robot arm never moves"),
)
KEEP = {  # the state kept, against a step that must bring about the opposite
    "close": (
        ("while keeping {x} closed the whole time", "while {x} stays shut throughout"),
        ("keep {x} closed the whole time", "make sure {x} stays shut throughout"),
    ),
    "open": (
        ("while keeping {x} open the whole time", "while {x} stays open throughout"),
        ("keep {x} open the whole time", "make sure {x} stays open throughout"),
    ),
    "turnoff": (
        ("while keeping {x} switched off the whole time", "while {x} stays off throughout"),
        ("keep {x} switched off the whole time", "make sure {x} stays off throughout"),
    ),
    "turnon": (
        ("while keeping {x} switched on the whole time", "while {x} stays on throughout"),
        ("keep {x} switched on the whole time", "make sure {x} stays on throughout"),
    ),
}
MOVING = ("place", "push", "move_aside")
PUSHING = ("push", "move_aside")
"""Steps an "untouched" constraint does not contradict: the thing can be pushed with a held object."""
STATES = ("open", "close", "turn_on", "turn_off")
LABELS = {
    "still": "goal vs. keeping the moved object still",
    "untouched": "goal vs. never touching the acted-on thing",
    "robot": "goal vs. a still robot arm",
    "keep": "state change vs. keeping the opposite state throughout",
}
DONE = {"open": "opened", "close": "closed", "turnon": "switched on", "turnoff": "switched off"}
STATE_WORD = {"open": "open", "close": "closed", "turnon": "on", "turnoff": "off"}
PLACE_WORDS = {"to", "behind", "in", "on", "next", "between", "at", "near"}
VARIANTS = 3
"""Phrasings drafted per combination of constraints."""


@dataclass
class Constraint:
    kind: str
    literal: list
    goal: list
    """The step's goal literal it contradicts."""
    attached: tuple[str, ...]
    """Phrasings that attach to the step ("without touching the bowl")."""
    standalone: tuple[str, ...]
    """Phrasings that stand as an imperative ("never touch the bowl")."""
    premise: str


def _full_name(model: TaskModel, entity: str) -> str:
    return model.name(entity) if entity in model.names else model.dest_phrases[entity][1]


def denotes_only(model: TaskModel, phrase: str, entity: str) -> bool:
    """Does the phrase fit the entity and nothing else in the scene? No other thing may carry a name
    or kind that contains it ("the sauce" is ambiguous beside a ketchup); the entity's own holder and
    regions do not count (a drawer's cabinet, the stove's cooking area)."""
    key = f" {' '.join(_words(phrase)).removeprefix('the ')} "
    own = {entity, model.parent(entity)} | {e for e in model.facts.entities if model.parent(e) == entity}
    others = (set(model.facts.entities) | set(model.problem.fixtures) | set(model.problem.objects)) - own
    return not any(
        key in f" {n} " and f" and{key}" not in f" {n} "  # "the white mug" is not "the yellow and white mug"
        for other in others
        for n in map(_joined, _names_and_kinds(model, other))
    )


def _names_and_kinds(model: TaskModel, entity: str) -> set[str]:
    """Its names, and the kinds it belongs to: "the sauce" could mean the ketchup (a sauce)."""
    cat = model.category_of(entity)
    kinds = set(category(cat).hypernyms) if cat in load_table() else set()
    # a place named after a landmark ("to the front of the stove") is not called the stove
    return {n for n in model.entity_names(entity) if n.split(" ")[0] not in PLACE_WORDS} | kinds


def _joined(name: str) -> str:
    return " ".join(_words(name))


def constraint_name(model: TaskModel, entity: str, rng: random.Random) -> str | None:
    """The entity's full name, or (half the time) a shorter ending of its head that still denotes it
    alone ("the pot" for "the moka pot", "the middle drawer" for "the middle drawer of the
    cabinet"). Only endings: they keep the head noun, so "the wine" never stands for "the wine
    bottle" (touching the bottle is not touching the wine), nor "the cabinet" for its drawer.
    ``None`` where even the full name fits something else."""
    full = _full_name(model, entity)
    head = bare(full).split(" of ")[0].split()  # "the middle drawer of the cabinet": "middle drawer"
    endings = [" ".join(head[i:]) for i in range(len(head))]
    parent = model.entity_names(model.parent(entity)) if model.parent(entity) != entity else set()
    short = [
        p
        for p in endings
        if p != bare(full) and p in model.entity_names(entity) - parent and denotes_only(model, p, entity)
    ]
    if short and rng.random() < 0.5:
        return f"the {short[-1]}"
    return full if denotes_only(model, full, entity) else None


def _goal(slot: Slot, obj: str) -> list:
    if slot.kind == "move_aside":
        return ["goal", "moved", obj]
    return ["goal", *next(a for a in slot.step.goal if obj in a[1:2])]


def _constraint(model: TaskModel, slot: Slot, kind: str, rng: random.Random) -> Constraint | None:
    if kind not in _kinds(slot):
        return None
    if slot.kind in MOVING:
        obj = choose(rng, slot.objects)
        goal = _goal(slot, obj)
        noun = bare(_full_name(model, obj))
        where = model.dest_text(slot.dest, slot.prep) if slot.dest else ""
        # as the added step is worded (frames.realise): "out of the way" only where that is true
        aside = "be moved out of the way" if model.in_the_way(obj) else "be picked up"
        must = {"move_aside": aside}.get(slot.kind, f"go {where}")
        x = constraint_name(model, obj, rng)
        if x is None and kind != "robot":
            return None
        if kind == "still":
            return _made(kind, ["keep", "still", obj], goal, STILL, x, f"the {noun} must {must} yet must not move")
        if kind == "untouched":
            premise = f"the {noun} must {must}, yet the robot may never touch it"
            return _made(kind, ["keep", "untouched", obj], goal, UNTOUCHED, x, premise)
        if kind == "robot":
            premise = f"the {noun} must {must}, which needs the robot arm to move, yet the arm must stay still"
            return _made(kind, ["keep", "still", "robot"], goal, ROBOT, x, premise)
        return None
    if slot.kind not in STATES:
        return None
    target = slot.objects[0]
    goal = ["goal", *slot.step.goal[0]]
    pred = goal[1]
    thing = bare(_full_name(model, target))
    x = constraint_name(model, target, rng)
    if x is None and kind != "robot":
        return None
    if kind == "keep":
        kept = EXCLUSIVE[pred]
        premise = f"the {thing} must be {DONE[pred]} yet stay {STATE_WORD[kept]} the whole time"
        return _made(kind, ["keep", kept, target], goal, KEEP[kept], x, premise)
    if kind == "untouched":
        premise = f"the {thing} must be {DONE[pred]}, yet the robot may never touch it"
        return _made(kind, ["keep", "untouched", target], goal, UNTOUCHED, x, premise)
    if kind == "robot":
        premise = f"the {thing} must be {DONE[pred]}, which needs the robot arm to move, yet the arm must stay still"
        return _made(kind, ["keep", "still", "robot"], goal, ROBOT, x, premise)
    return None


def _made(kind, literal, goal, phrases, x, premise) -> Constraint:
    attached, standalone = (tuple(p.format(x=x) for p in group) for group in phrases)
    return Constraint(kind, literal, goal, attached, standalone, premise)


def _kinds(slot: Slot) -> list[str]:
    if slot.kind in PUSHING:
        return ["still", "robot"]
    if slot.kind in MOVING:
        return ["still", "untouched", "robot"]
    if slot.kind == "close":
        return ["keep", "robot"]  # a drawer or door can be pushed shut with a held object
    if slot.kind in STATES:
        return ["keep", "untouched", "robot"]
    return []


def _phrase(made: list[Constraint], rng: random.Random) -> list[str]:
    """The constraints of one step as written, in order: one attaches ("without touching the bowl")
    or follows "but" ("but never touch the bowl"); a second joins with "and" ("without touching the
    bowl and without moving the robot arm") or stands as ", and" + imperative."""
    first = made[0]
    if len(made) == 1:
        if rng.random() < 0.6:
            return [choose(rng, first.attached)]
        return ["but " + choose(rng, first.standalone)]
    second = made[1]
    withouts = [[p for p in c.attached if p.startswith("without ")] for c in made]
    if all(withouts) and rng.random() < 0.5:
        return [choose(rng, withouts[0]), "and " + choose(rng, withouts[1])]
    return [choose(rng, first.attached), ", and " + choose(rng, second.standalone)]


def _frame(model: TaskModel, slot: Slot, made: list[Constraint], rng: random.Random) -> str | None:
    """A verb frame the constraints need: a carrying verb (never "move X onto Y", which pushing meets)
    for an untouched place step; else ``None``."""
    kinds = {c.kind for c in made}
    if slot.kind == "place" and "untouched" in kinds:
        obj = model.name(slot.objects[0]) if slot.objects[0] in model.names else ""
        options = [f for f in frames_for("place", slot.prep, slot.dest, obj) if not f.startswith("move ")]
        closed = [f for f in options if "{o} and" in f]  # a locating modifier cannot read as the destination
        locating = bool(set(slot.objects) & model.goal_twins())
        return choose(rng, closed if locating and closed else options)
    return None


def generate(model: TaskModel, level: str, rng: random.Random):
    states = model.facts.states()
    for frame in frames_for_level(model, level):
        options = [(i, k) for i, slot in enumerate(frame) for k in _kinds(slot)]
        if level in ("L1", "L3"):
            combos = [[o] for o in options]
        elif level == "L2":
            combos = [list(c) for c in itertools.combinations(options, 2) if c[0][0] == c[1][0]]
        else:
            combos = [list(c) for c in itertools.combinations(options, 2) if c[0][0] != c[1][0]]
        for _ in range(VARIANTS):
            for combo in combos:
                draft = _draft(model, level, frame, combo, rng, states)
                if draft:
                    yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, rng: random.Random, states) -> Draft | None:
    by_step: dict[int, list[Constraint]] = {}
    for index, kind in combo:
        made = _constraint(model, frame[index], kind, rng)
        if made is None or (made.goal[0] == "goal" and already(model.facts, made.goal, states)):
            return None  # a goal that already holds somewhere needs no change: nothing contradicts it
        by_step.setdefault(index, []).append(made)
    mods: dict[int, Mods] = {}
    written: list[tuple[int, str, Constraint]] = []
    for index, made in sorted(by_step.items()):
        texts = _phrase(made, rng)
        mods[index] = Mods(extras=texts, frame=_frame(model, frame[index], made, rng))
        for text, constraint in zip(texts, made):
            written.append((index, text.removeprefix(", and ").removeprefix("and ").removeprefix("but "), constraint))
    instruction, steps, clauses = realise(model, frame, mods, rng)
    requirements: list[dict] = []
    conflicts: list[list[str]] = []
    goal_ids: dict[tuple[int, str], str] = {}
    for index, text, constraint in written:
        key = (index, repr(constraint.goal))
        if key not in goal_ids:
            goal_ids[key] = f"r{len(requirements) + 1}"
            requirements.append(
                {"id": goal_ids[key], "step": index + 1, "text": clauses[index].body, "literal": constraint.goal}
            )
        rid = f"r{len(requirements) + 1}"
        requirements.append({"id": rid, "step": index + 1, "text": text, "literal": constraint.literal})
        conflicts.append([goal_ids[key], rid, "simultaneous"])
    witness = {"requirements": requirements, "conflicts": conflicts}
    if level == "L4" and not distinct_spread(factors_of(witness, "contradiction")):
        return None  # "... without moving the arm" after each step is one global conflict, not two factors
    return Draft(
        family="instruction",
        level=level,
        instruction=instruction,
        factors=tuple(step_label(level, i, LABELS[k]) for i, k in combo),
        premise="; ".join(c.premise for *_, c in written),
        witness={
            "type": "contradiction",
            **frame_witness(model, frame, steps),
            **witness,
        },
        operator="instruction.contradiction",
    )


OPERATORS = [("instruction.contradiction", "instruction", generate)]
