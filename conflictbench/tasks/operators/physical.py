"""Physical operators: a present, named entity asked to do or undergo what its nature rules out.

Rules of the family (re-checked by :mod:`conflictbench.tasks.validation.physical`):

- **Whole original.** Every case still asks for every subgoal of its base task, naming the original
  object and destination. The violation is an impossible manner of that same step ("fold the black
  bowl in half and put it on the plate"), a container a whole size class too small that the object
  must first go into ("squeeze the black bowl into the ramekin and put the black bowl on the plate":
  the object named again, never "it", after a holder), a fixture lifted before it is operated, or an
  added step BEFORE the original ones ("lift the stove, then put the bowl on the plate"). Never an
  added participant joined to the step ("together with the stove"): the goal is met before it.
- **Plainly denied.** Each violation pairs an entity of the scene, named in the text, with an
  affordance the table sets to ``false`` (never ``null``): ``foldable`` (rigidity), ``graspable`` or
  ``movable`` (fixed), ``fits_in`` from the size classes (size), ``container`` (containment),
  ``openable`` (articulation), ``turnable`` (switch), ``pourable`` (pouring). The
  operator is stricter than the table where a reader could hesitate: only furniture-sized fixtures
  other than the work surface are "fixed" (a microwave or wine rack can be lifted by a person), a
  plate is never a holder ("in the plate" is common for "on the plate"), nothing with a door or
  covers opens, the stove is never asked to open (read as an oven), and no holder (sealed or too
  small) is a box, carton, bag or package, nor a target or landmark of the task.
- **No disputable kinds.** Nothing is asked to rest on top of something (a plate balances on a
  bottle mouth, a box sits on a carton laid down): the ``support`` kind is never generated. A fixed
  fixture is always MOVED (lifted, carried, put somewhere with the object), never only held or
  touched: gripping a fixture in place is possible.
- **One pick-up per object.** No step grasps its object twice: a switch that follows another
  manner is "switch on the bowl", never "pick up the bowl, switch on the bowl and ...".
- **Readable.** One step never repeats a connective: two fixtures added to one step are
  coordinated ("together with the cabinet and the stove"), not chained.
- **Levels.** L1: one violation in the one step. L2: two violations of that one step, each
  impossible on its own (different entity or affordance). L3: exactly one violation, in an original
  step or in an added step before them. L4: violations in at least two different steps.
- **Varied.** Every violation records its ``kind``; each kind has several wordings, and the
  candidates of one cell are capped per (kinds, roles) signature so no kind or skeleton dominates.

The wordings and premise texts live in :mod:`.physical_wordings`.
"""

from __future__ import annotations

import itertools
import random
from dataclasses import dataclass

from conflictbench.tasks.scene.affordances import category, fits_inside
from conflictbench.tasks.scene.task_model import Step, TaskModel

from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, slot_of, step_label
from .phrasing import bare, choose
from .physical_wordings import (
    GRASPING_KINDS,
    INTO_ALONE,
    LIFT_ALONE,
    LIFT_FIRST,
    MANNERS,
    NAMED_TAILS,
    OPEN_ALONE,
    PREMISES,
    RIGID_ALONE,
    SWITCH_ALONE,
    SWITCH_HELD,
    TAILS,
)

KIND_NEEDS = {
    "rigidity": ("foldable",),
    "fixed": ("graspable", "movable"),
    "size": ("fits_in",),
    "containment": ("container",),
    "articulation": ("openable",),
    "switch": ("turnable",),
}
MANNER_NEEDS = {"rigidity": "foldable", "articulation": "openable", "switch": "turnable"}
CAP_PER_SIGNATURE = 4
"""Candidates kept per (kinds, roles) signature of a cell: keeps kinds and skeletons balanced."""
NOT_HOLDERS = ("box", "carton", "bag", "package")
"""Words in a holder's name that invite opening it: never a sealed holder."""


@dataclass(frozen=True)
class Option:
    """One violation a slot of a frame can carry, and how it is written."""

    step: int
    kind: str
    needs: str
    role: str
    """``manner`` (an impossible manner of the step's own object, composable with a second one),
    ``body`` (rewrites the step whole) or ``aux`` (a whole added step)."""
    wordings: tuple[tuple[str, str], ...]
    entity: str
    holder: str | None = None


def _info(model: TaskModel, entity: str):
    return category(model.category_of(entity))


def _objects(model: TaskModel, exclude: set[str]) -> list[str]:
    """Named, graspable bystanders an added step may act on."""
    return [
        e
        for e in model.names
        if e not in exclude
        and e not in model.unnamed
        and e not in model.goal_twins()
        and _info(model, e).has("graspable")
    ]


def _heavy_fixture(model: TaskModel, e: str) -> bool:
    """Furniture-sized fixtures a reader will agree no robot arm lifts: not the work surface."""
    info = _info(model, e)
    if info.size < 4 or info.has("fixed") is not True or not info.lacks("graspable"):
        return False
    return not {"table", "floor"} & set(info.names)


def _sealed(model: TaskModel, e: str) -> bool:
    """A holder nothing can be put inside: no container, plainly never opening, no box, carton, bag
    or package (those invite being opened), and not a plate ("in the plate" reads as "on")."""
    info = _info(model, e)
    names = " ".join((*info.names, model.name(e)))
    return (
        info.lacks("container")
        and info.lacks("openable")
        and info.category != "plate"
        and not any(w in names for w in NOT_HOLDERS)
    )


def _opens_never(model: TaskModel, e: str) -> bool:
    info = _info(model, e)
    return info.lacks("openable") and info.size < 4


def _too_big(model: TaskModel, item: str, holder: str) -> bool:
    """A real container a whole size class too small for the item (a bowl and a ramekin)."""
    holds = _info(model, holder).has("container")
    return bool(holds) and fits_inside(model.category_of(item), model.category_of(holder)) is False


def _exclusions(model: TaskModel) -> set[str]:
    """What an added step never acts on: the task's own objects and destinations (with their
    fixtures and landmarks, also those in a locating name), so no step's goal is touched."""
    out = model.targets() | {model.parent(t) for t in model.targets()}
    texts = [model.name(t) for t in model.targets() if t in model.names]
    texts += [model.dest_text(step.dest, step.prep) for step in model.steps if step.dest]
    for text in texts:
        out |= {e for e in model.names if model.name(e) in text}
    return out


def _object_name(model: TaskModel, entity: str) -> str:
    return model.name(entity) if entity in model.names else model.dest_phrases[entity][1]


def slot_options(model: TaskModel, index: int, slot: Slot, second: bool = False) -> list[Option]:
    """Every violation an original step can carry: only what is reached BEFORE or WHILE its subgoal
    is achieved (an episode ends at the original goal): a manner of its own object that comes first,
    a too-small container the object must first go into, a fixture lifted before it is operated.
    Never an added participant joined to the step ("together with", "both X and", "with X inside").
    A size manner names the object again after it ("... into the ramekin and put the bowl on the plate").
    ``second``: also the manners that may only come second in a step (a switch)."""
    if slot.aux:
        return []
    out: list[Option] = []
    o = slot.objects[0]
    one = len(slot.objects) == 1
    info = _info(model, o) if model.category_of(o) != "region" else None
    if slot.kind in TAILS and one and info is not None:
        for kind, needs in MANNER_NEEDS.items():
            denied = _opens_never(model, o) if kind == "articulation" else info.lacks(needs)
            if not denied:
                continue
            if kind in GRASPING_KINDS or second:
                out.append(Option(index, kind, needs, "manner", MANNERS[kind], o))
            else:
                out.append(Option(index, kind, needs, "manner", SWITCH_HELD, o))
        # No size manner ("squeeze X into H and put X on the plate"): putting X into H is a placement
        # with its own goal, a step of its own (suite 2.1); a too-small holder stays an added step.
    if slot.kind in LIFT_FIRST and one and _heavy_fixture(model, model.parent(o)):
        out.append(Option(index, "fixed", "graspable", "body", LIFT_FIRST[slot.kind], model.parent(o)))
    return out


def aux_options(model: TaskModel) -> list[Option]:
    """Added steps that are impossible in themselves, about bystanders only (never a target)."""
    targets = _exclusions(model)
    others = _objects(model, targets)
    out: list[Option] = []
    for f in model.names:
        if f not in targets and _heavy_fixture(model, f):
            out.append(Option(0, "fixed", "graspable", "aux", LIFT_ALONE, f))
    for y in others:
        info = _info(model, y)
        if info.lacks("foldable"):
            out.append(Option(0, "rigidity", "foldable", "aux", RIGID_ALONE, y))
        if _opens_never(model, y):
            out.append(Option(0, "articulation", "openable", "aux", OPEN_ALONE, y))
        if info.lacks("turnable"):
            out.append(Option(0, "switch", "turnable", "aux", SWITCH_ALONE, y))
        for h in others:
            if h == y:
                continue
            if _too_big(model, y, h):
                out.append(Option(0, "size", "fits_in", "aux", INTO_ALONE, y, h))
            elif _sealed(model, h):
                out.append(Option(0, "containment", "container", "aux", INTO_ALONE, h, y))
    return out


def _aux_slot(option: Option) -> Slot:
    acted = tuple(e for e in (option.entity, option.holder) if e)
    return Slot("move_aside", Step("move_aside", acted), acted, aux=True)


def _fill(model: TaskModel, text: str, slot: Slot, option: Option) -> str:
    """Put names into a wording: X the bystander acted on, H the holder, P a drawer's fixture."""
    o = _object_name(model, slot.objects[0]) if slot.objects else ""
    x, h = option.entity, option.holder
    if option.kind == "containment" and h:
        x, h = h, option.entity  # the bystander goes inside the sealed entity
    dest = slot.dest or slot.step.dest
    d = model.dest_text(dest, slot.step.prep) if dest else ""
    p = (
        model.name(model.parent(slot.objects[0]))
        if slot.objects and model.parent(slot.objects[0]) in model.names
        else ""
    )
    thing = slot.objects and model.category_of(slot.objects[0]) != "region"
    # a thing with an identical twin (libero_spatial's black bowls) is named in full every time: "turn
    # on the black bowl" beside its twin could mean either (suite 2.1's audit)
    twinned = thing and slot.objects[0] in model.goal_twins()
    short = o if twinned else f"the {_info(model, slot.objects[0]).names[0]}" if thing else ""
    return text.format(O=o, S=short, X=model.name(x), H=model.name(h) if h else "", P=p, d=d)


def _apply_manners(model, frame, mods, options: list[Option], rng: random.Random) -> list[dict]:
    """One step with one or two manners of its object: "open up the bowl, fold the bowl in half and
    put it on the plate". Each violation's text runs from the step's start to its own manner."""
    slot = frame[options[0].step]
    first, *rest = [choose(rng, o.wordings) for o in options]
    parts = [_fill(model, first[0], slot, options[0])] + [
        _fill(model, w[1], slot, o) for w, o in zip(rest, options[1:])
    ]
    # "it" needs a grasping verb just before it and one thing handled: after a holder ("it" could
    # mean the ramekin) or a switch that grasps nothing ("switch on X and put it"), name the object
    grasped = options[0].kind in GRASPING_KINDS or options[0].wordings == SWITCH_HELD
    named = any(o.holder for o in options) or not grasped
    tails = (NAMED_TAILS if named else TAILS)[slot.kind]
    joiner = ", " if tails else " and "  # "fold X in half, open X and put it ..." / "fold X in half and open X"
    texts = [joiner.join(parts[: i + 1]) for i in range(len(parts))]
    body = texts[-1] + (" and " + _fill(model, rng.choice(tails), slot, options[0]) if tails else "")
    mods.setdefault(options[0].step, Mods()).frame = body
    return [_violation(o, t) for o, t in zip(options, texts, strict=True)]


def _apply(model: TaskModel, frame: list[Slot], mods: dict[int, Mods], option: Option, rng: random.Random) -> dict:
    slot = frame[option.step]
    m = mods.setdefault(option.step, Mods())
    body, part = choose(rng, option.wordings)
    m.frame = _fill(model, body, slot, option)
    if option.role == "aux":
        m.obj = model.name(option.entity)
    return _violation(option, _fill(model, part, slot, option))


def _violation(option: Option, text: str) -> dict:
    v = {"step": option.step + 1, "kind": option.kind, "needs": option.needs, "entity": option.entity, "text": text}
    if option.holder and option.kind == "size":
        v["holder"] = option.holder
    return v


def _premise(model: TaskModel, v: dict) -> str:
    holder = model.name(v["holder"]) if "holder" in v else ""
    return PREMISES[v["needs"]].format(E=model.name(v["entity"]), H=holder)


def _compatible(options: tuple[Option, ...]) -> bool:
    """L2: two manners of the one object, of different kinds (each impossible on its own)."""
    return all(o.role == "manner" for o in options) and len({o.kind for o in options}) == len(options)


def _apart(options: tuple[Option, ...]) -> bool:
    """L4: violations in different steps, about different entities ("lift the cabinet, then ...
    lift the cabinet and open its drawer" repeats one impossibility)."""
    return len({o.step for o in options}) == len({o.entity for o in options}) == len(options)


def _combos(model: TaskModel, level: str) -> list[tuple[list[Slot], tuple[Option, ...]]]:
    if level in ("L1", "L2"):
        return _single_step_combos(model, level)
    frames = frames_for_level(model, level)
    plain = [f for f in frames if not any(s.aux for s in f)]
    if len(model.steps) == 1:
        plain.append([slot_of(model.steps[0])])
    out: list[tuple[list[Slot], tuple[Option, ...]]] = []
    for frame in frames:
        options = [o for i, s in enumerate(frame) for o in slot_options(model, i, s)]
        if level == "L3":
            out += [(frame, (o,)) for o in options]
        else:
            out += [(frame, c) for c in itertools.combinations(options, 2) if _apart(c)]
    return out + _added_step_combos(model, level, plain)


def _single_step_combos(model: TaskModel, level: str) -> list[tuple[list[Slot], tuple[Option, ...]]]:
    """L1: each violation of the one step; L2: two compatible ones of it."""
    out: list[tuple[list[Slot], tuple[Option, ...]]] = []
    for frame in frames_for_level(model, level):
        if level == "L1":
            out += [(frame, (o,)) for o in slot_options(model, 0, frame[0])]
            continue
        seconds = slot_options(model, 0, frame[0], second=True)
        pairs = itertools.product(slot_options(model, 0, frame[0]), seconds)
        out += [(frame, c) for c in pairs if _compatible(c)]
    return out


def _added_step_combos(model: TaskModel, level: str, plain: list[list[Slot]]) -> list:
    """A violating step added before each frame without one: alone (L3), or with a violation of a later
    step about another entity (L4)."""
    out = []
    for aux in aux_options(model):
        for frame in plain:
            full = [_aux_slot(aux), *frame]
            if level == "L3":
                out.append((full, (aux,)))
                continue
            for i, s in enumerate(frame):
                out += [(full, (aux, o)) for o in slot_options(model, i + 1, s) if _apart((aux, o))]
    return out


def generate(model: TaskModel, level: str, rng: random.Random):
    by_signature: dict[tuple, list] = {}
    for frame, combo in _combos(model, level):
        signature = (len(frame), tuple(sorted((o.kind, o.role) for o in combo)))
        by_signature.setdefault(signature, []).append((frame, combo))
    picked = []
    for signature in sorted(by_signature):
        group = by_signature[signature]
        rng.shuffle(group)
        picked += group[:CAP_PER_SIGNATURE]
    rng.shuffle(picked)
    for frame, combo in picked:
        for _ in range(3):  # more wordings: scenes with few entities still fill their cell
            draft = _draft(model, level, frame, combo, rng)
            if draft:
                yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    violations: list[dict] = []
    for step in sorted({o.step for o in combo}):
        here = [o for o in combo if o.step == step]  # in the combo's order: which manner is named first
        if here[0].role == "manner":
            violations += _apply_manners(model, frame, mods, here, rng)
        else:
            violations += [_apply(model, frame, mods, o, rng) for o in here]
    instruction, steps, _ = realise(model, frame, mods, rng)
    if any(v["text"] not in instruction for v in violations):
        return None
    return Draft(
        family="physical",
        level=level,
        instruction=instruction,
        factors=tuple(
            step_label(level, v["step"] - 1, f"{v['kind']}: {bare(model.name(v['entity']))} not {v['needs']}")
            for v in violations
        ),
        premise="; ".join(_premise(model, v) for v in violations),
        witness={"type": "affordance_violation", **frame_witness(model, frame, steps), "violations": violations},
        operator="physical.affordance_violation",
    )


OPERATORS = [("physical.affordance_violation", "physical", generate)]
