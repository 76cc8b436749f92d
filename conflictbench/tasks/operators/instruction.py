"""Instruction operators: requirements inside the text that cannot all be met.

A step's goal is paired with a constraint that rules it out: keep the object still or untouched,
keep the arm still, make sure the object does not end up where it is sent, keep the drawer shut
while opening it, never grasp what must be picked up. The witness lists every requirement as a
literal (:mod:`.contradictions`) and the pairs that contradict; validation re-derives each pair.
"""

from __future__ import annotations

import itertools
import random

from conflictbench.tasks.scene.task_model import TaskModel

from .contradictions import EXCLUSIVE, already
from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose

STILL = (
    "without moving {x}",
    "while keeping {x} exactly where it is",
    "but leave {x} exactly where it is",
    "without letting {x} leave its spot",
)
UNTOUCHED = ("without touching {x}", "without making any contact with {x}", "but never touch {x}")
AVOID = (
    "but make sure {x} does not end up {d}",
    "making sure {x} is not {d} at the end",
    "so that {x} ends up anywhere but {d}",
)
ROBOT = ("without moving the robot arm", "while keeping the arm completely still", "without moving the gripper at all")
UNGRASPED = ("without grasping {x}", "without ever closing the gripper on {x}")
KEEP = {
    "close": ("but keep {t} shut", "while leaving {t} closed", "but keep {t} closed the whole time"),
    "open": ("but keep {t} open", "while leaving {t} open the whole time"),
    "turnoff": ("but keep {t} switched off", "while leaving {t} off"),
    "turnon": ("but keep {t} running", "while leaving {t} on"),
}
END = {
    "close": "and make sure {t} is closed when you finish",
    "open": "and make sure {t} is open when you finish",
    "turnoff": "and make sure {t} is off at the end",
    "turnon": "and make sure {t} is on at the end",
}
GRASP_FRAME = "pick up {o} and place {it} {d}"
KINDS = ("still", "untouched", "avoid", "robot", "ungrasped", "keep", "end")


def _ref(model: TaskModel, entity: str, rng: random.Random) -> str:
    """How a constraint names an entity: its name, or "it" where the name carries a long modifier."""
    name = model.name(entity) if entity in model.names else model.dest_phrases[entity][1]
    return "it" if len(name.split()) > 4 or rng.random() < 0.2 else name


def _goal_literals(slot: Slot) -> list[list[str]]:
    if slot.kind == "pick":
        return [["do", "lift", slot.objects[0]]]
    return [["goal", *atom] for atom in slot.step.goal if slot.kind != "pick"]


def _kinds(slot: Slot) -> list[str]:
    if slot.kind in ("place", "push", "place_it"):
        return ["still", "untouched", "avoid", "robot"] + (["ungrasped"] if slot.kind == "place" else [])
    if slot.kind == "pick":
        return ["still", "untouched", "robot", "ungrasped"]
    if slot.kind == "move_aside":
        return ["still", "untouched", "robot"]
    if slot.kind in ("open", "close", "turn_on", "turn_off"):
        return ["keep", "untouched", "robot", "end"]
    return []


def _constraint(model: TaskModel, slot: Slot, kind: str, mods: Mods, rng: random.Random):
    """(constraint text, its literal, the goal literal it contradicts, the conflict in words) or None."""
    goals = _goal_literals(slot)
    if slot.kind in ("place", "push", "place_it", "pick", "move_aside"):
        obj = choose(rng, list(slot.objects))
        goal = next((g for g in goals if obj in g), goals[0])
        x = _ref(model, obj, rng) if not slot.pronoun else "it"
        noun = bare(model.name(obj))
        where = model.dest_text(slot.dest, slot.prep) if slot.dest else ""
        must = {"pick": "be picked up", "move_aside": "be moved out of the way"}.get(slot.kind, f"go {where}")
        if kind == "still":
            return (
                choose(rng, STILL).format(x=x),
                ["keep", "still", obj],
                goal,
                f"the {noun} must {must} yet must not move",
            )
        if kind == "untouched":
            return (
                choose(rng, UNTOUCHED).format(x=x),
                ["keep", "untouched", obj],
                goal,
                f"the {noun} must {must} without ever being touched",
            )
        if kind == "robot":
            return (
                choose(rng, ROBOT),
                ["keep", "still", "robot"],
                goal,
                f"moving the {noun} needs the arm to move, yet the arm must stay still",
            )
        if kind == "avoid" and goal[0] == "goal" and slot.dest:
            return (
                choose(rng, AVOID).format(x=x, d=where),
                ["avoid", *goal[1:]],
                goal,
                f"the {noun} must end up {where} and must not",
            )
        if kind == "ungrasped":
            if slot.kind == "place":
                if len(slot.objects) > 1:
                    return None
                mods.frame = GRASP_FRAME
                goal = ["do", "lift", obj]
            return (
                choose(rng, UNGRASPED).format(x=x),
                ["keep", "ungrasped", obj],
                goal,
                f"the {noun} must be picked up without being grasped",
            )
        return None
    target = slot.objects[0]
    goal = goals[0]
    pred = goal[1]
    thing = bare(model.dest_phrases[target][1] if target in model.dest_phrases else model.name(target))
    done = {"open": "opened", "close": "closed", "turnon": "switched on", "turnoff": "switched off"}
    state = {"open": "open", "close": "closed", "turnon": "on", "turnoff": "off"}
    if kind == "keep":
        return (
            choose(rng, KEEP[EXCLUSIVE[pred]]).format(t="it"),
            ["keep", EXCLUSIVE[pred], target],
            goal,
            f"the {thing} must be {done[pred]} yet stay {state[EXCLUSIVE[pred]]}",
        )
    if kind == "end":
        return (
            END[EXCLUSIVE[pred]].format(t="it"),
            ["goal", EXCLUSIVE[pred], target],
            goal,
            f"the {thing} must be {done[pred]} yet end up {state[EXCLUSIVE[pred]]}",
        )
    if kind == "untouched":
        parent = model.parent(target)
        return (
            choose(rng, UNTOUCHED).format(x=model.name(parent)),
            ["keep", "untouched", parent],
            goal,
            f"the {thing} must be {done[pred]} without touching the {bare(model.name(parent))}",
        )
    if kind == "robot":
        return (
            choose(rng, ROBOT),
            ["keep", "still", "robot"],
            goal,
            f"the {thing} must be {done[pred]}, yet the arm must stay still",
        )
    return None


def generate(model: TaskModel, level: str, rng: random.Random):
    for frame in frames_for_level(model, level):
        options = [(i, k) for i, slot in enumerate(frame) for k in _kinds(slot)]
        if level in ("L1", "L3"):
            combos = [[o] for o in options]
        elif level == "L2":
            combos = [list(c) for c in itertools.combinations(options, 2) if c[0][0] == c[1][0]]
        else:
            combos = [list(c) for c in itertools.combinations(options, 2) if c[0][0] != c[1][0]]
        for combo in combos:
            for _ in range(2):
                draft = _draft(model, level, frame, combo, rng)
                if draft:
                    yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    made_for: dict[int, list] = {}
    for index, kind in combo:
        made = _constraint(model, frame[index], kind, mods.setdefault(index, Mods()), rng)
        if made is None:
            return None
        if made[2][0] == "goal" and already(model.facts, made[2], model.facts.states()):
            return None
        made_for.setdefault(index, []).append(made)
    picked: list[tuple[int, str, list, list, str]] = []
    for index, made in made_for.items():
        # "without ..." before "but ...": "put it in the basket without touching it, but leave it where it is"
        made.sort(key=lambda m: m[0].startswith("but "))
        texts = [made[0][0]]
        for text, *_ in made[1:]:
            # one "but" per step reads naturally ("anywhere but" counts); a second joins with "and":
            # ", and never touch it"
            if not text.startswith("but ") or any(" but " in f" {t}" for t in texts):
                text = text.removeprefix("but ").removeprefix("while ").removeprefix("and ")
            texts.append(text)
        if len(set(texts)) < len(texts):
            return None
        mods[index].extras = [texts[0]] + [(", " if t.startswith("but ") else ", and ") + t for t in texts[1:]]
        picked += [(index, t, literal, goal, conflict) for t, (_, literal, goal, conflict) in zip(texts, made)]
    picked.sort(key=lambda p: p[0])
    instruction, steps, clauses = realise(model, frame, mods, rng)
    requirements: list[dict] = []
    conflicts: list[list[str]] = []
    goal_ids: dict[tuple[int, str], str] = {}
    for index, text, literal, goal, _ in picked:
        key = (index, repr(goal))
        if key not in goal_ids:
            goal_ids[key] = f"r{len(requirements) + 1}"
            requirements.append({"id": goal_ids[key], "step": index + 1, "text": clauses[index].body, "literal": goal})
        rid = f"r{len(requirements) + 1}"
        requirements.append({"id": rid, "step": index + 1, "text": text, "literal": literal})
        conflicts.append([goal_ids[key], rid])
    words = {
        "still": "goal vs. keeping it still",
        "untouched": "goal vs. not touching",
        "avoid": "goal vs. its negation",
        "robot": "goal vs. a still arm",
        "ungrasped": "picking up vs. not grasping",
        "keep": "state vs. its opposite",
        "end": "state vs. its opposite at the end",
    }
    return Draft(
        family="instruction",
        level=level,
        instruction=instruction,
        factors=tuple(step_label(level, i, words[k]) for i, k in combo),
        premise="; ".join(conflict for *_, conflict in picked),
        witness={
            "type": "contradiction",
            **frame_witness(model, frame, steps),
            "requirements": requirements,
            "conflicts": conflicts,
        },
        operator="instruction.contradiction",
    )


OPERATORS = [("instruction.contradiction", "instruction", generate)]
