"""Grounding operators: a referent of the instruction is replaced by something the scene lacks.

Roles a slot offers: the manipulated ``object``; its ``destination`` (a surface for "on", a
``receptacle`` for "in"); a ``landmark`` the object is located by ("the bowl next to the vase");
the ``appliance`` to switch on or the ``openable`` thing to open or close. Every replacement comes
from the absent-referent table and is checked absent for this scene (:func:`.lexicon.absent_for`):
not present, not a synonym of anything present, not a category of anything present.
"""

from __future__ import annotations

import itertools
import random

from conflictbench.tasks.scene.lexicon import AbsentConcept, absent_for
from conflictbench.tasks.scene.task_model import TaskModel

from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose

LANDMARK_RELATIONS = ("next to", "beside", "behind", "in front of", "to the left of", "to the right of")


def _roles(slot: Slot) -> list[str]:
    if slot.kind in ("place", "push"):
        dest_role = "receptacle" if slot.prep == "in" else "destination"
        return ["object", dest_role, "landmark"] if slot.prep is not None else ["object", "landmark"]
    if slot.kind in ("pick", "move_aside"):
        return ["object", "landmark"]
    if slot.kind == "place_it":
        return ["receptacle" if slot.prep == "in" else "destination"]
    if slot.kind in ("open", "close"):
        return ["openable"]
    if slot.kind in ("turn_on", "turn_off"):
        return ["appliance"]
    return []


_POOL = {
    "object": "object",
    "destination": "support",
    "receptacle": "container",
    "landmark": "landmark",
    "openable": "openable",
    "appliance": "appliance",
}


def _apply(model: TaskModel, slot: Slot, role: str, concept: AbsentConcept, mods: Mods, rng: random.Random) -> str:
    """Put the absent referent into the slot; returns the text span that names it."""
    np_ = f"the {concept.phrase}"
    if role == "object":
        if len(slot.objects) == 2:  # "both the soup and the <absent>" keeps the other object
            mods.obj = f"both {model.name(slot.objects[0])} and {np_}"
        else:
            mods.obj = np_
        return np_
    if role in ("destination", "receptacle"):
        if slot.dest and model.dest_phrases.get(slot.dest, ("", ""))[0] == "":
            # a relative destination ("to the right of the plate"): swap its landmark
            relation = model.dest_phrases[slot.dest][1].rsplit(" the ", 1)[0]
            mods.dest = f"{relation} {np_}"
        else:
            mods.dest = f"{'in' if role == 'receptacle' else 'on'} {np_}"  # "move" frames turn it into into/onto
        return np_
    if role == "landmark":
        base = mods.obj or (model.name(slot.objects[0]) if len(slot.objects) == 1 else None)
        if base is None:
            raise ValueError("no single object to locate")
        head = base.split(" between ")[0].split(" next to ")[0].split(" on ")[0].split(" in ")[0].split(" from ")[0]
        that = "that is " if slot.kind != "place" or rng.random() < 0.3 else ""
        mods.obj = f"{head} {that}{choose(rng, LANDMARK_RELATIONS)} {np_}"
        mods.locating = True
        return np_
    mods.obj = np_  # openable / appliance
    return np_


def _premise(concepts: list[AbsentConcept]) -> str:
    names = [bare(c.phrase) for c in concepts]
    if len(names) == 1:
        return f"there is no {names[0]} in the scene"
    return "the scene holds no " + ", no ".join(names[:-1]) + f" and no {names[-1]}"


def generate(model: TaskModel, level: str, rng: random.Random):
    pools = {role: absent_for(model.problem, kind) for role, kind in _POOL.items()}
    for frame in frames_for_level(model, level):
        slots_roles = [(i, r) for i, slot in enumerate(frame) for r in _roles(slot)]
        if level == "L1" or level == "L3":
            combos = [[sr] for sr in slots_roles]
        elif level == "L2":
            combos = [list(c) for c in itertools.combinations(slots_roles, 2) if c[0][0] == c[1][0]]
        else:
            combos = [list(c) for c in itertools.combinations(slots_roles, 2) if c[0][0] != c[1][0]]
        for combo in combos:
            for _ in range(3):  # a few draws of absent referents per combination
                draft = _draft(model, level, frame, combo, pools, rng)
                if draft:
                    yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, pools, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    chosen: list[tuple[int, str, AbsentConcept, str]] = []
    used: set[str] = set()
    # the object before its landmark: the landmark locates the (possibly replaced) object
    for index, role in sorted(combo, key=lambda c: (c[0], c[1] == "landmark")):
        pool = [c for c in pools[role] if c.concept not in used]
        if not pool:
            return None
        concept = choose(rng, pool)
        used.add(concept.concept)
        try:
            span = _apply(model, frame[index], role, concept, mods.setdefault(index, Mods()), rng)
        except ValueError:
            return None
        chosen.append((index, role, concept, span))
    instruction, steps, _ = realise(model, frame, mods, rng)
    referents = [{"step": i + 1, "role": role, "text": span, "concept": c.concept} for i, role, c, span in chosen]
    return Draft(
        family="grounding",
        level=level,
        instruction=instruction,
        factors=tuple(step_label(level, i, role) for i, role, _, _ in chosen),
        premise=_premise([c for _, _, c, _ in chosen]),
        witness={"type": "absent_referent", **frame_witness(model, frame, steps), "referents": referents},
        operator="grounding.absent_referent",
    )


OPERATORS = [("grounding.absent_referent", "grounding", generate)]
