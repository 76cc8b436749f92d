"""Physical operators: entities that are present, asked to do what their category cannot.

Each violation pairs a present, named entity with an affordance the action needs and the
affordance table plainly denies (``false``, never ``null``): carrying a fixture (``graspable``),
pushing furniture (``movable`` = not ``fixed``), putting something inside what has no inside
(``container``), resting something on a bottle (``support``), a bowl into a ramekin (``fits_in``),
opening a plate (``openable``), switching on a mug (``turnable``), folding a bowl (``foldable``),
pouring out butter (``pourable``).
"""

from __future__ import annotations

import itertools
import random

from conflictbench.tasks.scene.affordances import category, fits_inside
from conflictbench.tasks.scene.task_model import TaskModel

from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose

PREMISES = {
    "graspable": "{E} cannot be picked up and carried: {it} is part of the scene's furniture",
    "movable": "{E} is fixed in place and cannot be pushed anywhere",
    "container": "{E} has no inside, so nothing can be put in {it}",
    "support": "nothing can rest on top of {e}",
    "fits_in": "{E} is larger than {h} and cannot fit inside {it2}",
    "openable": "{E} has nothing that opens or closes",
    "turnable": "{E} has no switch and cannot be turned on or off",
    "foldable": "{E} is rigid and cannot be folded",
    "pourable": "{E} holds nothing that can be poured",
}
VERB_SWAPS = {  # needs -> frames per slot kind
    "foldable": {
        "place": "fold {o} in half and put {it} {d}",
        "pick": "fold {o} in half",
        "move_aside": "fold {o} in half",
    },
    "turnable": {"pick": "turn on {o}", "move_aside": "switch on {o}"},
    "openable": {"pick": "open {o}", "move_aside": "open {o}"},
    "pourable": {"place": "pour {o} {d}"},
}


SKIP_CATEGORIES = {"floor"}
"""Never named as the object of a physical conflict: nobody asks a robot to pick up the floor."""


def _named(model: TaskModel) -> list[str]:
    return [e for e in model.names if e not in model.unnamed and model.category_of(e) not in SKIP_CATEGORIES]


def short_name(model: TaskModel, entity: str) -> str:
    """The entity without the base task's locating phrase: its twin shares every affordance."""
    if entity in model.goal_twins():
        return f"the {category(model.category_of(entity)).names[0]}"
    return model.name(entity)


def _lacking(model: TaskModel, needs: str, exclude: set[str]) -> list[str]:
    out = []
    for e in _named(model):
        if e in exclude:
            continue
        info = category(model.category_of(e))
        if (needs == "movable" and info.has("fixed") is True) or (needs != "movable" and info.lacks(needs)):
            out.append(e)
    return out


def _options(model: TaskModel, slot: Slot) -> list[tuple[str, str, str | None]]:
    """(part, needs, frame) the slot can violate: part is object, verb, dest, target or a second target."""
    out: list[tuple[str, str, str | None]] = []
    if slot.kind in ("place", "pick"):
        out += [("object", "graspable", None), ("also", "graspable", None)]
    if slot.kind == "move_aside":  # pushed aside, not carried: what it needs is to be movable
        out += [("object", "movable", None), ("also", "movable", None)]
    if slot.kind in ("place", "pick", "move_aside") and len(slot.objects) == 1:
        for needs, frames in VERB_SWAPS.items():
            if slot.kind in frames and category(model.category_of(slot.objects[0])).lacks(needs):
                if needs != "pourable" or slot.prep in ("in", "on"):
                    out.append(("verb", needs, frames[slot.kind]))
    if slot.kind == "push":
        out += [("object", "movable", None), ("also", "movable", None)]
    if slot.kind in ("place", "place_it") and slot.prep in ("in", "on"):
        out.append(("dest", "container" if slot.prep == "in" else "support", None))
        if slot.prep == "in" and len(slot.objects) == 1:
            out.append(("dest", "fits_in", None))
    if slot.kind in ("open", "close"):
        out += [("target", "openable", None), ("also", "openable", None)]
    if slot.kind in ("turn_on", "turn_off"):
        out += [("target", "turnable", None), ("also", "turnable", None)]
    return out


def _mentioned(model: TaskModel, text: str) -> set[str]:
    return {e for e in model.names if model.name(e) in text}


def _apply(model, slot: Slot, option, mods: Mods, rng: random.Random, busy: set[str]) -> dict | None:
    part, needs, frame = option
    dest = slot.dest or slot.step.dest  # a pick step keeps its place step's destination out too
    dest_text = model.dest_text(dest, slot.step.prep) if dest else ""
    exclude = (
        busy | set(slot.step.objects) | _mentioned(model, dest_text) | ({dest, model.parent(dest)} if dest else set())
    )
    if part == "verb":
        entity = slot.objects[0]
        mods.frame = frame
        mods.obj = short_name(model, entity)
        if needs == "pourable":
            mods.dest = f"{'into' if slot.prep == 'in' else 'onto'} {model.dest_phrases[slot.dest][1]}"
        return {"entity": entity, "needs": needs, "text": mods.obj}
    if part in ("object", "target", "also"):
        pool = _lacking(model, needs, exclude)
        if not pool:
            return None
        entity = choose(rng, pool)
        name = short_name(model, entity)
        if part == "also":  # a second thing the same step acts on: "switch on both the plate and the rack"
            if not mods.obj:
                return None
            mods.obj = f"both {mods.obj} and {name}"
        elif len(slot.objects) == 2:  # "put both the soup and the stove in the basket"
            mods.obj = f"both {model.name(slot.objects[0])} and {name}"
        else:
            mods.obj = name
        mods.entity = entity
        return {"entity": entity, "needs": needs, "text": name}
    # the destination
    item = mods.entity or slot.objects[0]
    if needs == "fits_in":
        pool = [
            e
            for e in _named(model)
            if e not in exclude
            and e != item
            and fits_inside(model.category_of(item), model.category_of(e)) is False
            and category(model.category_of(e)).has("container")
        ]
    else:
        pool = _lacking(model, needs, exclude | {item})
    if not pool:
        return None
    entity = choose(rng, pool)
    prep = (
        ("into" if (mods.frame or "").startswith("pour") else "inside")
        if needs in ("container", "fits_in")
        else "on top of"
    )
    mods.dest = f"{prep} {short_name(model, entity)}"
    if needs == "fits_in":
        return {"entity": item, "needs": "fits_in", "holder": entity, "text": short_name(model, entity)}
    return {"entity": entity, "needs": needs, "text": short_name(model, entity)}


def _premise(model: TaskModel, v: dict) -> str:
    name = short_name(model, v["entity"])
    holder = short_name(model, v["holder"]) if "holder" in v else ""
    text = PREMISES[v["needs"]].format(E=name, e=name, it="it", h=holder, it2="it")
    return text


def generate(model: TaskModel, level: str, rng: random.Random):
    for frame in frames_for_level(model, level):
        options = [(i, o) for i, slot in enumerate(frame) for o in _options(model, slot)]
        if level in ("L1", "L3"):
            combos = [[o] for o in options]
        elif level == "L2":  # two parts of one step; a swapped object keeps its own verb
            combos = [
                list(c)
                for c in itertools.combinations(options, 2)
                if c[0][0] == c[1][0]
                and c[0][1][0] != c[1][1][0]
                and "verb" not in (c[0][1][0], c[1][1][0])
                or c[0][0] == c[1][0]
                and {c[0][1][0], c[1][1][0]} == {"verb", "dest"}
            ]
        else:
            combos = [list(c) for c in itertools.combinations(options, 2) if c[0][0] != c[1][0]]
        for combo in combos:
            for _ in range(3):
                draft = _draft(model, level, frame, combo, rng)
                if draft:
                    yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    violations: list[dict] = []
    busy: set[str] = set()
    order = {"object": 0, "target": 0, "also": 1, "verb": 1, "dest": 2}
    for index, option in sorted(combo, key=lambda c: (c[0], order[c[1][0]])):
        v = _apply(model, frame[index], option, mods.setdefault(index, Mods()), rng, busy)
        if v is None:
            return None
        busy.add(v["entity"])
        violations.append({"step": index + 1, **v})
    instruction, steps, _ = realise(model, frame, mods, rng)
    if any(v["text"] not in instruction for v in violations):
        return None
    return Draft(
        family="physical",
        level=level,
        instruction=instruction,
        factors=tuple(
            step_label(
                level,
                v["step"] - 1,
                f"{bare(short_name(model, v['entity']))} not {v['needs']}"
                if v["needs"] != "fits_in"
                else f"{bare(short_name(model, v['entity']))} does not fit",
            )
            for v in violations
        ),
        premise="; ".join(_premise(model, v) for v in violations),
        witness={"type": "affordance_violation", **frame_witness(model, frame, steps), "violations": violations},
        operator="physical.affordance_violation",
    )


OPERATORS = [("physical.affordance_violation", "physical", generate)]
