"""Grounding operators: a referent the instruction needs is absent from the scene.

The substituted role is always the MANIPULATED OBJECT (for a state step, the drawer or appliance
it operates), the DESTINATION (a surface for "on") or the RECEPTACLE (for "in"); never only a
landmark the object is located by. Each replacement stands in for one scene entity of an ORIGINAL
step (its witness says which: ``replaces``); only at L4 may one of the two factors be the object of
an added step, which comes first, so the conflict is reached before the episode can end.

Referents come from three sources, drawn per referent with weights :data:`SOURCE_WEIGHTS`
(0.4 / 0.4 / 0.2, renormalised over the sources a slot can use). Wrong attributes exist only in the
25 base tasks with a colour-known category (none in libero_object), and only in colours far from
every present one, so the built suite (seed 0) ends at about 44 % libero, 22 % attribute and 35 %
out-of-domain referents:

- ``libero``: a LIBERO category absent from the scene that shares no name, synonym, near-synonym,
  hypernym or head noun with anything present (:func:`.lexicon.libero_absent`): "the moka pot";
- ``attribute``: a WRONG COLOUR of a present category, far from every present colour and every
  colour a reader could take one for (:func:`.lexicon.wrong_colours`; wood reads as yellow, orange,
  tan, beige, brown or gold): "the red bowl" where the bowls are black; it replaces an entity
  of that very category, keeping any locating phrase after the noun;
- ``out_of_domain``: an item of ``data/absent_referents.jsonl`` absent here: "the banana".

A receptacle referent is never a word a reader could map onto an open receptacle present
(:func:`.lexicon.receptacle_problem`: no "bucket" beside a desk caddy).

Levels: L1 one step, one referent; L2 one step, the object AND its destination or receptacle
(two different roles, so both change what can be grounded); L3 several steps, one referent in an
original step; L4 referents in two different steps. A replacement fits: a receptacle is a size class
larger than what goes in (or a large container), a surface is at least as large as what goes on it.
"""

from __future__ import annotations

import hashlib
import itertools
import random
from dataclasses import dataclass

from conflictbench.tasks.scene.affordances import category
from conflictbench.tasks.scene.lexicon import (
    absent_concepts,
    absent_for,
    colourings,
    libero_absent,
    receptacle_problem,
    wrong_colours,
)
from conflictbench.tasks.scene.lexicon import concept as absent_concept
from conflictbench.tasks.scene.task_model import TaskModel

from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose, coordinate

SOURCE_WEIGHTS = {"libero": 0.4, "attribute": 0.4, "out_of_domain": 0.2}
DRAWS = 24
"""Drafts tried per frame, shared among its combinations of replaced roles (at least 3 each)."""
NARROW = {"desk_caddy": 1, "vase": 1, "flowerpot": 1, "colander": 1, "paper_bag": 1}
"""Receptacles whose opening only takes hand-sized things (no plate in the desk caddy)."""
MAX_CARRIED = 2
"""The largest size class a replaced manipulated object may have (no "pick up the basket")."""
_TABLE_ROLES = {"object": "object", "support": "destination", "container": "receptacle"}
_TABLE_ROLES |= {"openable": "openable", "appliance": "appliance"}


@dataclass(frozen=True)
class Referent:
    concept: str
    phrase: str
    source: str
    size: int
    can: frozenset[str]
    """What it can stand in for: object, destination, receptacle, openable, appliance."""
    category: str | None = None
    """For a wrong attribute: the present category whose colour it gets wrong."""
    attribute: str | None = None


def _abilities(cat: str) -> frozenset[str]:
    info = category(cat)
    flags = {"graspable": "object", "support": "destination", "container": "receptacle"}
    flags |= {"openable": "openable", "turnable": "appliance"}
    out = {role for flag, role in flags.items() if info.has(flag) is True}
    if info.size > MAX_CARRIED:
        out.discard("object")
    if info.has("fixed") is not True:
        out.discard("openable")  # "close the black book" for "close the microwave" reads oddly
    return frozenset(out)


def referent_pool(model: TaskModel) -> list[Referent]:
    """Every absent referent this scene allows, from all three sources."""
    problem, out = model.problem, []
    for cat in libero_absent(problem):
        out.append(Referent(cat, category(cat).name, "libero", category(cat).size, _abilities(cat)))
    present = {model.category_of(e) for e in model.names}
    for cat, colouring in colourings().items():
        if cat in present:
            for colour in wrong_colours(colouring.noun, problem):
                phrase = f"{colour} {colouring.noun}"
                out.append(Referent(cat, phrase, "attribute", category(cat).size, _abilities(cat), cat, colour))
    usable = {c.concept for role in _TABLE_ROLES for c in absent_for(problem, role)}
    for c in absent_concepts():
        if c.concept in usable:
            can = {_TABLE_ROLES[r] for r in c.roles} - ({"object"} if c.size > MAX_CARRIED else set())
            can = frozenset(can)
            out.append(Referent(c.concept, c.phrase, "out_of_domain", c.size, can))
    return out


# -- slots and roles ------------------------------------------------------------------------------
def _dest_role(model: TaskModel, slot: Slot) -> str | None:
    if not slot.dest or model.dest_phrases.get(slot.dest, ("", ""))[0] == "":
        return None  # a destination relative to a landmark ("to the right of the plate"): not a referent
    return "receptacle" if slot.prep == "in" else "destination"


def _roles(model: TaskModel, slot: Slot) -> list[str]:
    if slot.kind in ("place", "push"):
        return ["object"] + ([_dest_role(model, slot)] if _dest_role(model, slot) else [])
    if slot.kind in ("move_aside", "open", "close", "turn_on", "turn_off"):
        return ["object"]
    return []


def _ability(slot: Slot, role: str) -> str:
    if role != "object":
        return role
    return {"open": "openable", "close": "openable", "turn_on": "appliance", "turn_off": "appliance"}.get(
        slot.kind, "object"
    )


def _replaced_entity(model: TaskModel, slot: Slot, role: str, rng: random.Random) -> str:
    return choose(rng, slot.objects) if role == "object" else slot.dest


def _holder(model: TaskModel, entity: str) -> str:
    return model.category_of(model.parent(entity))


def _fits(model: TaskModel, slot: Slot, picks: dict[str, tuple[str, Referent]]) -> bool:
    """Sizes agree: what goes in is smaller than the receptacle (or that is large); a surface is at
    least as large as what goes on it."""
    dest_role = _dest_role(model, slot)
    if slot.kind not in ("place", "push") or dest_role is None:
        return True
    if "object" in picks:
        obj_size = picks["object"][1].size
    else:
        obj_size = max(category(model.category_of(o)).size for o in slot.objects)
    dest_size = picks[dest_role][1].size if dest_role in picks else category(_holder(model, slot.dest)).size
    if dest_role == "receptacle":
        holder = picks[dest_role][1].concept if dest_role in picks else _holder(model, slot.dest)
        return obj_size < dest_size and obj_size <= NARROW.get(holder, obj_size)
    return obj_size <= dest_size


def _rank(model: TaskModel, role: str, referent: Referent) -> str:
    """A per-task order of the candidates, so tasks of one LIBERO suite prefer different referents
    (their instructions differ only in the part a referent replaces)."""
    key = f"{model.task.suite}|{model.task.task_id}|{role}|{referent.concept}|{referent.phrase}"
    return hashlib.sha256(key.encode()).hexdigest()


def referent_synonyms(concept: str, source: str) -> tuple[str, ...]:
    if source == "libero":
        return tuple(category(concept).synonyms)
    known = absent_concept(concept) if source == "out_of_domain" else None
    return tuple(known.synonyms) if known else ()


def _candidates(model: TaskModel, pool: list[Referent], slot: Slot, role: str, entity: str) -> list[Referent]:
    out = []
    for r in pool:
        if _ability(slot, role) not in r.can:
            continue
        if role == "receptacle" and r.source != "attribute":
            if receptacle_problem(r.phrase, referent_synonyms(r.concept, r.source), model.problem):
                continue  # "the bucket" reads as the desk caddy: the only open, bin-like receptacle
        if r.source == "attribute":
            target = model.category_of(entity) if role == "object" and slot.kind not in ("open", "close") else None
            if r.category not in {target, _holder(model, entity)}:
                continue  # a wrong colour stands in for a thing of its own category
        out.append(r)
    return sorted(out, key=lambda r: _rank(model, role, r))


def _pick_source(rng: random.Random, by_source: dict[str, list[Referent]]) -> str | None:
    sources = [s for s in SOURCE_WEIGHTS if by_source.get(s)]
    if not sources:
        return None
    weights = [SOURCE_WEIGHTS[s] for s in sources]
    return rng.choices(sources, weights=weights)[0]


# -- writing the referent into the step -----------------------------------------------------------
def _swap_holder(model: TaskModel, phrase: str, holder: str, new: str) -> str:
    """ "the top drawer of the wooden cabinet" -> "the top drawer of the red cabinet"."""
    name = model.name(holder)
    return phrase.replace(name, new) if name in phrase and name != phrase else new


def _apply(model: TaskModel, slot: Slot, role: str, entity: str, ref: Referent, mods: Mods) -> str:
    """Put the referent into the slot; returns the text span that names it."""
    new = f"the {ref.phrase}"
    if role == "object" and slot.kind in ("open", "close", "turn_on", "turn_off"):
        current = model.dest_phrases[entity][1] if entity not in model.names else model.name(entity)
        mods.obj = _swap_holder(model, current, model.parent(entity), new) if ref.source == "attribute" else new
    elif role == "object":
        name = model.name(entity)
        noun = next(n for n in sorted(category(model.category_of(entity)).names, key=len, reverse=True) if n in name)
        tail = name[name.index(noun) + len(noun) :]  # "between the plate and the ramekin" still locates it
        phrase = new + tail
        mods.obj = coordinate([phrase if o == entity else model.name(o) for o in slot.objects])
        mods.locating = bool(tail.strip())
    else:
        prep, current = model.dest_phrases[entity]
        if ref.source == "attribute":
            mods.dest = f"{slot.prep or prep} {_swap_holder(model, current, model.parent(entity), new)}"
        else:
            mods.dest = f"{'in' if role == 'receptacle' else 'on'} {new}"
    return new


def _premise(refs: list[Referent]) -> str:
    names = [bare(r.phrase) for r in refs]
    if len(names) == 1:
        return f"there is no {names[0]} in the scene"
    return "the scene holds no " + ", no ".join(names[:-1]) + f" and no {names[-1]}"


def _combos(model: TaskModel, level: str, frame: list[Slot]) -> list[list[tuple[int, str]]]:
    slot_roles = [(i, r) for i, slot in enumerate(frame) for r in _roles(model, slot)]
    original = [(i, r) for i, r in slot_roles if not frame[i].aux]
    if level in ("L1", "L3"):
        return [[sr] for sr in original]
    if level == "L2":  # the object AND where it goes: two roles of the one step
        return [list(c) for c in itertools.combinations(original, 2) if c[0][0] == c[1][0] and c[0][1] != c[1][1]]
    return [  # L4: two steps, at most one of them added
        list(c)
        for c in itertools.combinations(slot_roles, 2)
        if c[0][0] != c[1][0] and not (frame[c[0][0]].aux and frame[c[1][0]].aux)
    ]


def generate(model: TaskModel, level: str, rng: random.Random):
    pool = referent_pool(model)
    for frame in frames_for_level(model, level):
        combos = _combos(model, level, frame)
        for combo in combos:
            for _ in range(max(3, DRAWS // len(combos))):
                draft = _draft(model, level, frame, combo, pool, rng)
                if draft:
                    yield draft


def _draft(model: TaskModel, level: str, frame: list[Slot], combo, pool, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    chosen: list[tuple[int, str, str, Referent]] = []
    used: set[str] = set()
    for index, role in combo:
        slot = frame[index]
        entity = _replaced_entity(model, slot, role, rng)
        by_source: dict[str, list[Referent]] = {}
        for r in _candidates(model, pool, slot, role, entity):
            if r.concept not in used and r.phrase not in used:
                by_source.setdefault(r.source, []).append(r)
        source = _pick_source(rng, by_source)
        if source is None:
            return None
        options = by_source[source]
        ref = choose(rng, options[: max(3, len(options) // 2)])  # this task's preferred half
        used |= {ref.concept, ref.phrase}
        chosen.append((index, role, entity, ref))
    for index in {i for i, _, _, _ in chosen}:
        picks = {role: (entity, ref) for i, role, entity, ref in chosen if i == index}
        if not _fits(model, frame[index], picks):
            return None
    spans = [_apply(model, frame[i], role, entity, ref, mods.setdefault(i, Mods())) for i, role, entity, ref in chosen]
    instruction, steps, _ = realise(model, frame, mods, rng)
    referents = []
    for (i, role, entity, ref), span in zip(chosen, spans):
        referents.append(
            {
                "step": i + 1,
                "role": role,
                "text": span,
                "concept": ref.concept,
                "source": ref.source,
                "replaces": entity,
                **({"attribute": ref.attribute} if ref.attribute else {}),
            }
        )
    return Draft(
        family="grounding",
        level=level,
        instruction=instruction,
        factors=tuple(step_label(level, i, role) for i, role, _, _ in chosen),
        premise=_premise([ref for _, _, _, ref in chosen]),
        witness={"type": "absent_referent", **frame_witness(model, frame, steps), "referents": referents},
        operator="grounding.absent_referent",
    )


OPERATORS = [("grounding.absent_referent", "grounding", generate)]
