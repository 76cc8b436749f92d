"""Conflict operators: the shared machinery (drafts, step frames, realisation) and the registry.

An operator is ``generate(model, level, rng) -> iterable of Draft``: given a base task (as a
:class:`~.frames.TaskModel`) and a level, it proposes conflict cases of its family. Levels:

- L1: one step, one conflict factor;
- L2: one step, several factors on that same requirement;
- L3: several ordered steps, one factor in one step, the other steps plausible;
- L4: several steps, two distinct factors in different steps.

A *step* is a manipulation with its own goal: an object moved to a place, an articulated fixture
changed, a device switched. Reaching for an object and placing it is ONE step (suite 2.0 wrote
"grab the bowl, then put it on the plate" as two; readers in every family counted it as one).

A *frame* is the list of steps an instruction will have; every frame asks for the WHOLE base task.
The single-step frame is the base task's one step of one object (a task of two subgoals, such as
"put both X and Y in the basket", has none); multi-step frames take all base steps when there are
several, give each object of a two-object placing its own step, or put a plausible extra step the
scene allows BEFORE the base task (open a closed drawer, switch on a stove that is off, move a
bystander object: "out of the way" only where it stands near what the task touches).

Built-in operators register through the ``conflictbench_register_conflict_operators`` hook like
any plugin's (:mod:`conflictbench.tasks` holds the implementation).
"""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import Any

from conflictbench.tasks.scene.affordances import category
from conflictbench.tasks.scene.task_model import Step, TaskModel

from .phrasing import Clause, coordinate, join

SINGLE_LEVELS = ("L1", "L2")


@dataclass(frozen=True)
class Draft:
    """A proposed conflict case, before it gets its id and status."""

    family: str
    level: str
    instruction: str
    factors: tuple[str, ...]
    premise: str
    witness: dict[str, Any]
    init_states: tuple[int, ...] | None = None
    operator: str = ""


@dataclass
class Slot:
    kind: str
    """Clause kind: place, push, open, close, turn_on, turn_off, move_aside."""
    step: Step
    objects: tuple[str, ...]
    dest: str | None = None
    prep: str | None = None
    aux: bool = False


@dataclass
class Mods:
    """What an operator changes in one slot of a frame."""

    obj: str | None = None
    dest: str | None = None
    frame: str | None = None
    extras: list[str] = field(default_factory=list)
    locating: bool = False
    """The object phrase carries a locating modifier (see :class:`.phrasing.Clause`)."""
    entity: str | None = None
    """The entity a replaced object phrase now names (physical operators check its affordances)."""


def slot_of(step: Step, aux: bool = False) -> Slot:
    return Slot(step.kind, step, step.objects, step.dest, step.prep, aux)


def aux_steps(model: TaskModel) -> list[Slot]:
    """Plausible extra steps: each can be done in every initial state, touches no target, and moves
    nothing the reference instruction names nor anything another object rests on or in."""
    out: list[Slot] = []
    targets = model.targets() | {model.parent(t) for t in model.targets()}
    for name, entity in sorted(model.facts.entities.items()):
        if (
            entity.kind == "region"
            and "drawer" in model.dest_phrases.get(name, ("", ""))[1]
            and name not in targets
            and model.parent(name) in model.names
        ):
            if model.never("open", name):
                out.append(Slot("open", Step("open", (name,), goal=(("open", name),)), (name,), aux=True))
    for name in model.fixtures():
        if category(model.category_of(name)).has("turnable") and name not in targets:
            if model.never("turnon", name) and model.facts.predicate("turnoff", name):
                out.append(Slot("turn_on", Step("turn_on", (name,), goal=(("turnon", name),)), (name,), aux=True))
    said = f" {model.task.language} "
    for name in model.objects():
        info = category(model.category_of(name))
        # Never move what the reference instruction names: "the bowl between the plate and the
        # ramekin" no longer picks out the bowl once the ramekin has been pushed aside.
        named = any(f" {n} " in said for n in model.entity_names(name))
        if info.has("graspable") and name not in targets and not named and not _carries(model, name):
            out.append(Slot("move_aside", Step("move_aside", (name,), goal=(("moved", name),)), (name,), aux=True))
    return out


def _carries(model: TaskModel, entity: str) -> bool:
    """Does anything rest on or in the entity in some initial state? Moving it would move that too."""
    holders = {entity} | {r for r, e in model.facts.entities.items() if e.kind == "region" and e.parent == entity}
    return any(
        states and atom[0] in ("on", "in") and atom[2] in holders and atom[1] != entity
        for atom, states in model.facts.predicates.items()
        if len(atom) == 3
    )


def single_frames(model: TaskModel) -> list[list[Slot]]:
    """One step asking for the whole base task: only a base task of one manipulation has one (a task
    of two subgoals, "put both X and Y in the basket" included, is two manipulations, so its L1 and
    L2 cells stay empty)."""
    one = len(model.steps) == 1 and len(model.steps[0].goal) == 1
    return [[slot_of(model.steps[0])]] if one else []


def multi_frames(model: TaskModel) -> list[list[Slot]]:
    """Several steps, each a manipulation with its own goal, that together ask for the whole base
    task. Added steps only ever come FIRST: an episode ends as soon as the original goal holds, so a
    step after the original ones is never reached and a conflict there could not be observed."""
    frames: list[list[Slot]] = []
    if len(model.steps) >= 2:
        frames.append([slot_of(s) for s in model.steps])
    for i, step in enumerate(model.steps):
        if step.kind == "place" and len(step.objects) == 2:
            one = [Slot("place", step, (o,), step.dest, step.prep) for o in step.objects]
            frames.append([slot_of(s) for s in model.steps[:i]] + one + [slot_of(s) for s in model.steps[i + 1 :]])
    if len(model.steps) == 1:
        for aux in aux_steps(model):
            frames.append([aux, slot_of(model.steps[0])])
    return [f for f in frames if len(f) >= 2]


def step_goals(slot: Slot) -> list[list[str]]:
    """The base task's goal literals a step of a frame achieves (none for an added step)."""
    if slot.aux:
        return []
    return [list(atom) for atom in slot.step.goal if slot.kind not in ("place", "push") or atom[1] in slot.objects]


def acted_on(model: TaskModel, slot: Slot) -> list[str]:
    """Entities a step moves or operates (a drawer's region and its cabinet): a later step's spatial
    premise about them may have been made true by this step."""
    out = list(slot.objects)
    if slot.kind in ("open", "close", "turn_on", "turn_off"):
        out += [model.parent(o) for o in slot.objects if model.parent(o) not in out]
    return out


def frame_witness(model: TaskModel, frame: list[Slot], bodies: list[str]) -> dict:
    """The witness fields every family shares: the steps as written, their roles, their goals and
    what each acts on (checked by :mod:`conflictbench.tasks.validation.structure`)."""
    return {
        "steps": list(bodies),
        "step_roles": ["added" if slot.aux else "original" for slot in frame],
        "step_goals": [step_goals(slot) for slot in frame],
        "step_entities": [acted_on(model, slot) for slot in frame],
    }


def frames_for_level(model: TaskModel, level: str) -> list[list[Slot]]:
    return single_frames(model) if level in SINGLE_LEVELS else multi_frames(model)


AUX_FRAMES = {"move_aside": ("move {o} out of the way", "push {o} aside", "slide {o} to one side")}
"""Wordings of an added step that claim something of the scene: only where it is true (``in_the_way``)."""
PLAIN_AUX_FRAMES = {"move_aside": ("pick up {o} and set it back down", "lift {o} and put it back down")}
"""The same added step, claiming nothing: for a bystander far from what the task touches."""


def realise(
    model: TaskModel, frame: list[Slot], mods: dict[int, Mods], rng: random.Random
) -> tuple[str, list[str], list[Clause]]:
    """Write a frame as one instruction; returns (instruction, step bodies, clauses)."""
    clauses: list[Clause] = []
    for i, slot in enumerate(frame):
        m = mods.get(i, Mods())
        obj = m.obj or coordinate(
            [model.name(o) if o in model.names else model.dest_phrases[o][1] for o in slot.objects]
        )
        dest = m.dest if m.dest is not None else (model.dest_text(slot.dest, slot.prep) if slot.dest else None)
        frame_text = m.frame
        if frame_text is None and slot.kind in AUX_FRAMES:
            wordings = AUX_FRAMES if model.in_the_way(slot.objects[0]) else PLAIN_AUX_FRAMES
            frame_text = wordings[slot.kind][rng.randrange(len(wordings[slot.kind]))]
        clause = Clause(
            slot.kind,
            obj,
            dest,
            plural=len(slot.objects) > 1,
            frame=frame_text,
            extras=list(m.extras),
            locating=m.locating or (m.obj is None and bool(set(slot.objects) & model.goal_twins())),
        )
        clause.render(rng, prep=slot.prep)
        clauses.append(clause)
    # The witness's steps are the clause bodies: a reviewer may re-punctuate the constraints
    # around them without breaking the witness.
    return join([c.text for c in clauses], rng), [c.body for c in clauses], clauses


def step_label(level: str, index: int, what: str) -> str:
    """Factor label: plain for single-step levels, ``step k: ...`` for multi-step ones."""
    return what if level in SINGLE_LEVELS else f"step {index + 1}: {what}"
