"""Physical operators: a present, named entity asked to do or undergo what its nature rules out.

Rules of the family (re-checked by :mod:`conflictbench.tasks.validation.physical`):

- **Whole original.** Every case still asks for every subgoal of its base task, naming the original
  object and destination. The violation is an impossible manner of that same step ("fold the black
  bowl in half and put it on the plate"), an added participant or property of it ("put the bowl on
  the plate together with the stove", "... with the butter tucked inside the ketchup"), or an added
  step BEFORE the original ones ("lift the stove, then put the bowl on the plate").
- **Plainly denied.** Each violation pairs an entity of the scene, named in the text, with an
  affordance the table sets to ``false`` (never ``null``): ``foldable`` (rigidity), ``graspable`` or
  ``movable`` (fixed), ``fits_in`` from the size classes (size), ``container`` (containment),
  ``openable`` (articulation), ``turnable`` (switch), ``pourable`` (pouring). The
  operator is stricter than the table where a reader could hesitate: only furniture-sized fixtures
  other than the work surface are "fixed" (a microwave or wine rack can be lifted by a person), a
  plate is never a holder ("in the plate" is common for "on the plate"), nothing with a door or
  covers opens, and the stove is never asked to open (read as an oven).
- **No disputable kinds.** Nothing is asked to rest on top of something (a plate balances on a
  bottle mouth, a box sits on a carton laid down): the ``support`` kind is never generated. A fixed
  fixture is always MOVED (lifted, carried, put somewhere with the object), never only held or
  touched: gripping a fixture in place is possible.
- **Readable.** One step never repeats a connective: two fixtures added to one step are
  coordinated ("together with the cabinet and the stove"), not chained.
- **Levels.** L1: one violation in the one step. L2: two violations of that one step, each
  impossible on its own (different entity or affordance). L3: exactly one violation, in an original
  step or in an added step before them. L4: violations in at least two different steps.
- **Varied.** Every violation records its ``kind``; each kind has several wordings, and the
  candidates of one cell are capped per (kinds, roles) signature so no kind or skeleton dominates.
"""

from __future__ import annotations

import itertools
import random
from dataclasses import dataclass

from conflictbench.tasks.scene.affordances import category, fits_inside
from conflictbench.tasks.scene.task_model import Step, TaskModel

from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, slot_of, step_label
from .phrasing import bare, choose, coordinate

KIND_NEEDS = {
    "rigidity": ("foldable",),
    "fixed": ("graspable", "movable"),
    "size": ("fits_in",),
    "containment": ("container",),
    "articulation": ("openable",),
    "switch": ("turnable",),
    "pouring": ("pourable",),
}
PREMISES = {
    "foldable": "{E} is rigid and cannot be folded or bent",
    "graspable": "{E} is heavy furniture fixed in the scene: the robot cannot pick it up or carry it",
    "movable": "{E} is heavy furniture fixed in the scene and cannot be pushed anywhere",
    "fits_in": "{E} is larger than {H} and cannot fit inside it",
    "container": "{E} is sealed or solid: nothing can be put inside it",
    "openable": "{E} has no lid, door or drawer: there is nothing to open or close",
    "turnable": "{E} has no switch or knob: it cannot be turned on or off",
    "pourable": "{E} is a solid food: it cannot be poured",
}
CAP_PER_SIGNATURE = 4
"""Candidates kept per (kinds, roles) signature of a cell: keeps kinds and skeletons balanced."""

# Wordings. {O}: the step's object as named by the task; {X}: the violating entity; {H}: a holder;
# {d}: the step's destination phrase. Each entry is (text of the step body or clause, violating part).
RIGID_PLACE = (
    ("fold {O} in half and put it {d}", "fold {O} in half"),
    ("bend {O} in half and place it {d}", "bend {O} in half"),
    ("fold {O} flat and set it down {d}", "fold {O} flat"),
)
RIGID_ALONE = (("fold {X} in half", "fold {X} in half"), ("bend {X} in half", "bend {X} in half"))
OPEN_PLACE = (("open {O} and put it {d}", "open {O}"), ("open up {O} and place it {d}", "open up {O}"))
OPEN_ALONE = (("open {X}", "open {X}"), ("open up {X}", "open up {X}"))
RIGID_PUSH = (
    ("fold {O} in half and slide it {d}", "fold {O} in half"),
    ("bend {O} in half and slide it {d}", "bend {O} in half"),
)
OPEN_PUSH = (("open {O} and slide it {d}", "open {O}"),)
SWITCH_ALONE = (("switch on {X}", "switch on {X}"), ("turn on {X}", "turn on {X}"), ("turn {X} on", "turn {X} on"))
POUR_PLACE = (("pour {O} {into}", "pour {O}"), ("pour {O} out {into}", "pour {O} out"))
LIFT_ALONE = (("lift {X}", "lift {X}"), ("pick up {X}", "pick up {X}"), ("lift {X} and set it down again", "lift {X}"))
INTO_ALONE = (("put {X} inside {H}", "{X} inside {H}"), ("stuff {X} inside {H}", "{X} inside {H}"))
PICK_INTO = (("pick up {O} and put it inside {H}", "inside {H}"), ("grab {O} and place it inside {H}", "inside {H}"))
TUCKED = ("{X} tucked inside {H}", "{X} packed inside {H}")
TOGETHER = ("together with {X}",)
CARRYING = ("while carrying {X}", "while lifting up {X}")
GRASPING = ("fold ", "bend ", "open ", "pick up ", "grab ", "lift ", "take ")
"""Body openers that leave the object in hand, so the next step may say "place it"."""
CONNECTIVES = ("together with ", "while carrying ", "while lifting up ")
"""Clause openers: a second added participant of the same step joins the first clause's list."""


@dataclass(frozen=True)
class Option:
    """One violation a slot of a frame can carry, and how it is written."""

    step: int
    kind: str
    needs: str
    role: str
    """``body`` (rewrites the step), ``obj`` (adds a participant to the object), ``with`` (a "with
    ..." property clause), ``extra`` (a trailing clause) or ``aux`` (a whole added step)."""
    wordings: tuple[tuple[str, str], ...]
    entity: str
    holder: str | None = None


def short_name(model: TaskModel, entity: str) -> str:
    """A bystander's name; a goal twin ("the black bowl between ...") keeps its locating phrase."""
    return model.name(entity)


def _info(model: TaskModel, entity: str):
    return category(model.category_of(entity))


def _objects(model: TaskModel, exclude: set[str]) -> list[str]:
    """Named, graspable things a clause may add as participants."""
    return [
        e
        for e in model.names
        if e not in exclude
        and e not in model.unnamed
        and e not in model.goal_twins()
        and _info(model, e).has("graspable")
    ]


def _heavy_fixtures(model: TaskModel, exclude: set[str]) -> list[str]:
    """Furniture-sized fixtures a reader will agree no robot arm lifts: not the work surface."""
    out = []
    for e in model.names:
        info = _info(model, e)
        if e in exclude or info.size < 4 or info.has("fixed") is not True or not info.lacks("graspable"):
            continue
        if {"table", "floor"} & set(info.names):
            continue
        out.append(e)
    return out


def _sealed(model: TaskModel, e: str) -> bool:
    """A holder nothing can be put inside: no container, nothing that opens, and not a plate."""
    info = _info(model, e)
    return info.lacks("container") and info.has("openable") is not True and info.category != "plate"


def _opens_never(model: TaskModel, e: str) -> bool:
    info = _info(model, e)
    return info.lacks("openable") and info.size < 4


def _too_big(model: TaskModel, item: str, holder: str) -> bool:
    """A real container a whole size class too small for the item (a bowl and a ramekin)."""
    holds = _info(model, holder).has("container")
    return bool(holds) and fits_inside(model.category_of(item), model.category_of(holder)) is False


def _food(model: TaskModel, e: str) -> bool:
    return "food" in _info(model, e).hypernyms


def _exclusions(model: TaskModel) -> set[str]:
    """What a violation never adds as a participant: the task's own objects and destinations (with
    their fixtures and landmarks, also those in a locating name: "the black bowl on the stove" is
    never put down "together with the stove"), so no step's goal is touched by a violation."""
    out = model.targets() | {model.parent(t) for t in model.targets()}
    texts = [model.name(t) for t in model.targets() if t in model.names]
    texts += [model.dest_text(step.dest, step.prep) for step in model.steps if step.dest]
    for text in texts:
        out |= {e for e in model.names if model.name(e) in text}
    return out


def _object_name(model: TaskModel, entity: str) -> str:
    return model.name(entity) if entity in model.names else model.dest_phrases[entity][1]


def slot_options(model: TaskModel, index: int, slot: Slot) -> list[Option]:
    """Every violation a step of a frame can carry (aux steps carry none: violating ones are built whole)."""
    if slot.aux:
        return []
    out: list[Option] = []
    exclude = _exclusions(model)
    o = slot.objects[0]
    one = len(slot.objects) == 1
    info = _info(model, o) if model.category_of(o) != "region" else None
    twin = o in model.goal_twins()
    others = _objects(model, exclude)

    def add(kind, needs, role, wordings, entity, holder=None):
        out.append(Option(index, kind, needs, role, tuple(wordings), entity, holder))

    if slot.kind in ("place", "pick", "push") and one and info is not None:
        wordings = {"place": 0, "pick": 1, "push": 2}[slot.kind]
        if info.lacks("foldable"):
            add("rigidity", "foldable", "body", (RIGID_PLACE, RIGID_ALONE, RIGID_PUSH)[wordings], o)
        if _opens_never(model, o):
            add("articulation", "openable", "body", (OPEN_PLACE, OPEN_ALONE, OPEN_PUSH)[wordings], o)
        if info.lacks("turnable") and slot.kind == "pick":  # "switch on X and put it ..." has no grasp for "it"
            add("switch", "turnable", "body", SWITCH_ALONE, o)
        if slot.kind == "place" and slot.prep in ("in", "on") and info.lacks("pourable") and _food(model, o):
            add("pouring", "pourable", "body", POUR_PLACE, o)
        if slot.kind == "pick":
            for h in others:
                if _too_big(model, o, h):
                    add("size", "fits_in", "body", PICK_INTO, o, h)
                elif _sealed(model, h):
                    add("containment", "container", "body", PICK_INTO, h, o)
    if slot.kind in ("place", "pick", "place_it") and not twin:
        for x in others:
            for h in slot.objects:
                if _sealed(model, h) and x != h:
                    add("containment", "container", "with", tuple((w, w) for w in TUCKED), h, x)
                if _too_big(model, h, x) and slot.kind != "pick":  # not "grab the book with the book in ..."
                    add("size", "fits_in", "with", tuple((w, w) for w in TUCKED), h, x)
    if slot.kind in ("place", "place_it", "push"):
        needs = "movable" if slot.kind == "push" else "graspable"
        for f in _heavy_fixtures(model, exclude):
            add("fixed", needs, "extra", tuple((w, w) for w in TOGETHER), f)
            if slot.kind != "place_it" and not (twin and slot.kind == "place"):
                add("fixed", needs, "obj", (("", ""),), f)
    if slot.kind in ("open", "close"):
        for y in others:
            if _opens_never(model, y):
                add("articulation", "openable", "obj", (("", ""),), y)
    if slot.kind in ("turn_on", "turn_off"):
        for y in others:
            if _info(model, y).lacks("turnable"):
                add("switch", "turnable", "obj", (("", ""),), y)
    if slot.kind in ("open", "close", "turn_on", "turn_off"):
        parents = {model.parent(x) for x in slot.objects}
        for f in _heavy_fixtures(model, exclude | parents):
            add("fixed", "graspable", "extra", tuple((w, w) for w in CARRYING), f)
    return out


def aux_options(model: TaskModel) -> list[Option]:
    """Added steps that are impossible in themselves, about bystanders only (never a target)."""
    targets = _exclusions(model)
    others = _objects(model, targets)
    out: list[Option] = []
    for f in _heavy_fixtures(model, targets):
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
    """Put names into a wording: X is the entity acted on, H the holder or surface."""
    o = _object_name(model, slot.objects[0]) if slot.objects else ""
    x, h = option.entity, option.holder
    if option.kind == "containment" and h:
        x, h = h, option.entity  # the participant goes inside or on top of the violating entity
    dest = slot.dest or slot.step.dest
    d = model.dest_text(dest, slot.step.prep) if dest else ""
    into = d.replace("in ", "into ", 1) if d.startswith("in ") else d.replace("on ", "onto ", 1)
    return text.format(O=o, X=model.name(x), H=model.name(h) if h else "", d=d, into=into)


def _apply(model: TaskModel, frame: list[Slot], mods: dict[int, Mods], option: Option, rng: random.Random) -> dict:
    slot = frame[option.step]
    m = mods.setdefault(option.step, Mods())
    body, part = choose(rng, option.wordings)
    body, part = _fill(model, body, slot, option), _fill(model, part, slot, option)
    if option.role in ("body", "aux"):
        m.frame, m.obj = body, model.name(option.entity) if option.role == "aux" else m.obj
        after = option.step + 1
        grasps = body.startswith(GRASPING) and " it " not in f" {body} "
        if option.role == "body" and not grasps and after < len(frame) and frame[after].pronoun:
            # "pick up X and put it inside Y, then place it ...": X or Y? "switch on X, then place it":
            # nothing was picked up. The next step names X again.
            mods.setdefault(after, Mods()).obj = _object_name(model, frame[after].objects[0])
    elif option.role == "obj":
        m.obj = coordinate([_object_name(model, o) for o in slot.objects] + [model.name(option.entity)])
        part = model.name(option.entity)
    elif option.role == "with":
        m.extras.append(("with " if not any(e.startswith("with ") for e in m.extras) else "and ") + body)
    else:
        part = _join_extra(m.extras, body)
    v = {"step": option.step + 1, "kind": option.kind, "needs": option.needs, "entity": option.entity, "text": part}
    if option.holder and option.kind == "size":
        v["holder"] = option.holder
    return v


def _join_extra(extras: list[str], clause: str) -> str:
    """Add a trailing clause; a second added participant joins the first clause ("together with the
    cabinet and the stove", never "together with the cabinet together with the stove" nor "while
    carrying the cabinet while lifting up the stove"). Returns the clause as it now reads."""
    opener = next((c for c in CONNECTIVES if clause.startswith(c)), None)
    for i, old in enumerate(extras):
        if opener and old.startswith(CONNECTIVES):
            extras[i] = f"{old} and {clause.removeprefix(opener)}"
            return extras[i]
    extras.append(clause)
    return clause


def _premise(model: TaskModel, v: dict) -> str:
    holder = model.name(v["holder"]) if "holder" in v else ""
    return PREMISES[v["needs"]].format(E=model.name(v["entity"]), H=holder)


def _compatible(options: tuple[Option, ...]) -> bool:
    """Two violations of one step must each stand alone: one rewrite of the body at most, one added
    object at most, different (entity, affordance) pairs, and no rewrite alongside an added object."""
    roles = [o.role for o in options]
    if roles.count("body") > 1 or roles.count("obj") > 1 or ("body" in roles and "obj" in roles):
        return False
    if "with" in roles and "extra" in roles:  # "... with X inside Y together with Z": whose Z?
        return False
    keys = {(o.entity, o.needs) for o in options}
    added = [o.holder for o in options if o.role == "with"]
    if len(added) != len(set(added)):
        return False  # "with the sauce inside the ketchup and the sauce on top of it": one thing twice
    return len(keys) == len(options)


def _apart(options: tuple[Option, ...]) -> bool:
    """L4: violations in different steps, about different entities ("lift the cabinet, then ...
    while carrying the cabinet" repeats one impossibility)."""
    return len({o.step for o in options}) == len({o.entity for o in options}) == len(options)


def _combos(model: TaskModel, level: str) -> list[tuple[list[Slot], tuple[Option, ...]]]:
    out: list[tuple[list[Slot], tuple[Option, ...]]] = []
    if level in ("L1", "L2"):
        for frame in frames_for_level(model, level):
            options = slot_options(model, 0, frame[0])
            size = 1 if level == "L1" else 2
            out += [(frame, c) for c in itertools.combinations(options, size) if _compatible(c)]
        return out
    frames = frames_for_level(model, level)
    plain = [f for f in frames if not any(s.aux for s in f)]
    if len(model.steps) == 1:
        plain.append([slot_of(model.steps[0])])
    for frame in frames:
        options = [o for i, s in enumerate(frame) for o in slot_options(model, i, s)]
        if level == "L3":
            out += [(frame, (o,)) for o in options]
        else:
            out += [(frame, c) for c in itertools.combinations(options, 2) if _apart(c)]
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
        for _ in range(2):  # a second wording: scenes with few entities still fill their cell
            draft = _draft(model, level, frame, combo, rng)
            if draft:
                yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    order = {"aux": 0, "body": 0, "obj": 1, "with": 2, "extra": 3}
    violations = [_apply(model, frame, mods, o, rng) for o in sorted(combo, key=lambda o: (o.step, order[o.role]))]
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
