"""Spatial operators: a relational description that is false in the initial scene.

Every entity stays present and named; what breaks is the relation the words presuppose ("the
ketchup to the left of the basket" where the ketchup starts to its right, "the black bowl on the
cookie box" where no bowl touches the box). The family's rules (checked again by
:mod:`conflictbench.tasks.validation.spatial`, which every draft passes before it is yielded):

- a claim is about every entity the subject's words could pick out and is false for all of them,
  under the lenient reading of :meth:`.scene.facts.TaskFacts.holds`, in every initial state the
  case is paired with: all 50 where possible, otherwise the listed states (at least
  ``MIN_STATES``);
- a direction is false by a margin a camera shows: the subject's centre lies past the landmark's
  centre, on the other side, by at least max(6 cm, the subject's radius); the witness gives the
  smallest such clearance over the paired states as ``margin_m``;
- no claim about an entity with an identical twin (the black bowls of libero_spatial): readers
  attached "the black bowl next to the ramekin that is behind the stove" to the ramekin as readily
  as to the bowl, so the plate or an added step carries the relation instead;
- the claim is still false when its step is reached: no earlier step moves or operates its subject
  or landmarks (or their fixtures, or a thing they rest on or in), and its own step does not move
  its landmark;
- readable: no "left"/"right" word in a phrase of a left/right claim (nor "front"/"back" for
  front/behind), "on"/"in" only with a real support or container at least the subject's size;
- never a destination: every description is a relative clause or a participle ("the butter that
  is to the left of the milk", "the bowl sitting on the plate"), whatever the verb, since after a
  motion verb a bare one ("take the butter to the left of the milk") reads as where to put it;
- landmarks resolve: each denotes one thing; a twin (either black bowl) is never a landmark, as
  its bare noun means both and its full name inside another description reads as a tangle;
- L2: two parts of the one step (object and destination), or two different claims about one part.

Finding the claims themselves (:func:`claims`, landmark selection) lives in :mod:`.spatial_claims`.
"""

from __future__ import annotations

import itertools
import random

from conflictbench.core import ConflictCase
from conflictbench.tasks.scene.facts import DIRECTIONS
from conflictbench.tasks.scene.task_model import TaskModel
from conflictbench.tasks.validation.spatial import (
    MIN_STATES,
    check_relation,
    frame_independent,
    referent_combos,
    riders,
)
from conflictbench.tasks.validation.structure import check_structure
from conflictbench.tasks.validation.text import names_in

from .frames import Draft, Mods, Slot, acted_on, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose, frames_for
from .spatial_claims import PHRASES, _names, claims, subject_noun

__all__ = ["MIN_STATES", "OPERATORS", "claims", "generate", "subject_noun"]
NEGATED = {
    "left_of": "to the left of",
    "right_of": "to the right of",
    "in_front_of": "in front of",
    "behind": "behind",
    "next_to": "next to",
    "on": "on",
    "in": "in",
    "between": "between",
}


def _subject_of(model: TaskModel, slot: Slot, part: str) -> str | None:
    if part == "object":
        if len(slot.objects) != 1 or slot.kind not in ("place", "push", "move_aside"):
            return None
        if slot.objects[0] in model.goal_twins():
            # "the black bowl between the plate and the ramekin that is left of the stove": readers
            # attach the clause to the ramekin as often as to the bowl. A twin gets no spatial claim.
            return None
        return slot.objects[0]
    if part == "dest" and slot.dest and slot.kind in ("place", "push"):
        holder = model.parent(slot.dest)
        return holder if holder in model.names and holder in model.facts.entities else None
    if part == "target" and slot.kind in ("open", "close", "turn_on", "turn_off"):
        holder = model.parent(slot.objects[0])
        return holder if holder in model.names and holder in model.facts.entities else None
    return None


def _phrase(claim: dict, rng: random.Random) -> str:
    """ "the bowl that is behind the stove", "the bowl sitting on the plate": always a relative
    clause or a participle, since after a motion verb ("take the butter to the left of the milk")
    a bare relation reads as where to put the thing, a destination the robot can satisfy."""
    rel = choose(rng, PHRASES[claim["relation"]])
    if rel.startswith(("sitting", "resting")):
        form = "{s} {r} {l}"
    else:
        form = choose(rng, ("{s} that is {r} {l}", "{s} that is {r} {l}", "{s} which is {r} {l}"))
    return form.format(s=claim["subject"], r=rel, l=claim["landmark_text"])


def _apply(
    model: TaskModel, slot: Slot, part: str, claim: dict, mods: Mods, rng: random.Random, earlier: str | None = None
) -> str:
    if earlier:  # a second claim about the same thing: "the plate behind the stove and next to the rack"
        text = f"{earlier} and {choose(rng, PHRASES[claim['relation']])} {claim['landmark_text']}"
        if part in ("object", "target"):
            mods.obj = (mods.obj or "").replace(earlier, text)
        else:
            mods.dest = (mods.dest or "").replace(earlier, text)
        return text
    text = _phrase(claim, rng)
    if part == "object":
        mods.locating = True
    if part in ("object", "target"):
        if part == "target" and slot.objects[0] != model.parent(slot.objects[0]):
            # a drawer: "the top drawer of the cabinet that is next to the stove"
            np_ = model.dest_phrases[slot.objects[0]][1]
            mods.obj = np_.replace(model.name(model.parent(slot.objects[0])), text)
        else:
            mods.obj = text
        if part == "target":  # "turn the stove that is left of the rack on" splits the verb
            mods.frame = choose(rng, [f for f in frames_for(slot.kind, None, None, mods.obj) if f.endswith("{o}")])
        return text
    prep, np_ = model.dest_phrases[slot.dest]
    prep = slot.prep or prep  # "put the cream cheese in the bowl" stays "in"
    holder = model.name(model.parent(slot.dest))
    mods.dest = f"{prep} {np_.replace(holder, text)}".strip() if holder in np_ else f"{prep} {np_} {text}".strip()
    return text


def _premise(model: TaskModel, claim: dict) -> str:
    subject = bare(claim["subject"])
    many = sum(1 for c in claim["candidates"] if model.facts.entities[c].kind != "region") > 1
    rel = NEGATED[claim["relation"]]
    who = f"no {subject}" if many else f"the {subject}"
    verb = "is" if many else "is not"
    where = claim["landmark_text"]
    return f"{who} {verb} {rel} {where} in the initial scene"


def _margin(model: TaskModel, claim: dict, states: frozenset) -> float | None:
    """The smallest gap between the footprints along the relation's axis over the paired states
    (directions only): how far the claim is false."""
    if claim["relation"] not in DIRECTIONS:
        return None
    idx = sorted(states)
    return round(
        min(
            float(model.facts.footprint_gap(claim["relation"], a, b)[idx].min())
            for a in claim["candidates"]
            for b in claim["landmark_groups"][0]
        ),
        3,
    )


def generate(model: TaskModel, level: str, rng: random.Random):
    cache: dict[tuple, list[dict]] = {}

    def claims_for(entity: str, avoid: frozenset, holder_avoid: frozenset) -> list[dict]:
        key = (entity, avoid, holder_avoid)
        if key not in cache:
            cache[key] = claims(model, entity, avoid, holder_avoid)
        return cache[key]

    for frame in frames_for_level(model, level):
        if _stale(model, frame):
            continue
        parts = [
            (i, p) for i, slot in enumerate(frame) for p in ("object", "dest", "target") if _usable(model, frame, i, p)
        ]
        if level in ("L1", "L3"):
            combos = [[p] for p in parts]
        elif level == "L2":  # two parts of one step, or two claims about one part
            combos = [list(c) for c in itertools.combinations(parts, 2) if c[0][0] == c[1][0]] + [[p, p] for p in parts]
        else:
            combos = [list(c) for c in itertools.combinations(parts, 2) if c[0][0] != c[1][0]]
        for combo in combos:
            for _ in range(6):
                draft = _draft(model, level, frame, combo, claims_for, rng)
                if draft:
                    yield draft


def _stale(model: TaskModel, frame: list[Slot]) -> bool:
    """An added step moves what a later step's own name describes the object by ("slide the
    ramekin aside, then pick up the bowl between the plate and the ramekin")."""
    for i, slot in enumerate(frame):
        if not slot.aux:
            continue
        moved = _touched(model, [slot])
        later = " ".join(model.name(o) for s in frame[i + 1 :] for o in s.objects if o in model.names)
        if any(names_in(later, _names(model, e)) for e in moved):
            return True
    return False


def _touched(model: TaskModel, slots: list[Slot]) -> set[str]:
    out = {e for slot in slots for e in acted_on(model, slot)}
    out |= {model.parent(e) for e in out}
    return out | {o for e in out for o in riders(model, e)}


def _usable(model: TaskModel, frame: list[Slot], index: int, part: str) -> bool:
    """A part can carry a claim when it has a subject no earlier step has moved or operated."""
    subject = _subject_of(model, frame[index], part)
    return bool(subject) and not ({subject, model.parent(subject)} & _touched(model, frame[:index]))


def _avoid(model: TaskModel, frame: list[Slot], index: int, subject: str) -> tuple[frozenset, frozenset]:
    slot = frame[index]
    avoid = _touched(model, frame[: index + 1]) - {subject}
    dest = slot.step.dest if slot.kind in ("place", "push") else None
    holder_avoid = frozenset({dest, model.parent(dest)} - {None}) if dest else frozenset()
    if dest and not model.dest_phrases[dest][0]:  # "to the right of the plate": no claim about the plate
        avoid |= {e for e in model.names if names_in(model.dest_phrases[dest][1], {model.name(e)})}
    return frozenset(avoid), holder_avoid


def _earlier_claim(chosen: list[tuple], index: int, part: str) -> tuple[dict | None, str | None]:
    """The claim already placed on this step's part, and its text (a part may carry two), or (None, None)."""
    return next(((c, t) for i, p, c, t in chosen if (i, p) == (index, part)), (None, None))


def _beside(claim: dict, first: dict) -> bool:
    """Whether ``claim`` can join ``first`` on one part: another relation, to a landmark neither names
    (not "in its drawer, left of the cabinet"), and neither of them a relation that locates it alone."""
    return (
        claim["relation"] != first["relation"]
        and claim["landmark_text"] not in first["landmark_text"]
        and first["landmark_text"] not in claim["landmark_text"]
        and claim["relation"] not in ("between", "on", "in")
        and first["relation"] != "between"
    )


def _claim_pool(model, frame, index, part, claims_for, states: frozenset, chosen, first: dict | None) -> list[dict]:
    """The false claims about this part's subject that may be chosen: false in enough of the initial states
    left, compatible with the claim the part already carries (``first``), and not one chosen already."""
    subject = _subject_of(model, frame[index], part)
    avoid, holder_avoid = _avoid(model, frame, index, subject)
    pool = [c for c in claims_for(subject, avoid, holder_avoid) if len(c["false_states"] & states) >= MIN_STATES]
    if first is not None:
        pool = [c for c in pool if _beside(c, first)]
    seen = {(c["relation"], c["subject"], c["landmark_text"]) for _, _, c, _ in chosen}
    return [c for c in pool if (c["relation"], c["subject"], c["landmark_text"]) not in seen]


def _relation(model: TaskModel, step: int, text: str, claim: dict, states: frozenset) -> dict:
    """The witness's record of one false relation placed in the instruction."""
    return {
        "step": step,
        "text": text,
        "relation": claim["relation"],
        "subject": {"phrase": bare(claim["subject"]), "entities": sorted(claim["candidates"])},
        "landmarks": [{"phrase": bare(p), "entities": sorted(model.candidates(p))} for p in claim["landmark_phrases"]],
        **({"margin_m": _margin(model, claim, states)} if claim["relation"] in DIRECTIONS else {}),
        "frame_independent": frame_independent(
            model, claim["relation"], referent_combos([sorted(claim["candidates"]), *claim["landmark_groups"]]), states
        ),
    }


def _draft(model, level, frame, combo, claims_for, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    chosen = []
    states = model.facts.states()
    for index, part in combo:
        first, earlier = _earlier_claim(chosen, index, part)
        pool = _claim_pool(model, frame, index, part, claims_for, states, chosen, first if earlier else None)
        if not pool:
            return None
        full = [c for c in pool if c["false_states"] == model.facts.states()]
        claim = choose(rng, full if full and rng.random() < 0.85 else pool)
        states = states & claim["false_states"]
        text = _apply(model, frame[index], part, claim, mods.setdefault(index, Mods()), rng, earlier)
        chosen.append((index, part, claim, text))
    instruction, steps, _ = realise(model, frame, mods, rng)
    if any(text not in instruction for *_, text in chosen):
        return None
    relations = [_relation(model, i + 1, text, c, states) for i, _, c, text in chosen]
    draft = Draft(
        family="spatial",
        level=level,
        instruction=instruction,
        factors=tuple(
            step_label(level, i, f"{part} relation ({c['relation'].replace('_', ' ')})") for i, part, c, _ in chosen
        ),
        premise="; ".join(_premise(model, c) for _, _, c, _ in chosen),
        witness={
            "type": "false_relation",
            **frame_witness(model, frame, steps),
            "relations": relations,
            "frame_independent": all(r["frame_independent"] for r in relations),
        },
        init_states=None if states == model.facts.states() else tuple(sorted(states)),
        operator="spatial.false_relation",
    )
    return draft if _passes(model, draft, states) else None


def _passes(model: TaskModel, draft: Draft, states: frozenset) -> bool:
    """The family's and the shared structural rules, checked before a draft is offered (a long
    locating phrase can push "pick up" out of the pronoun's reach, for one)."""
    case = ConflictCase(
        case_id="draft",
        suite=model.task.suite,
        task_id=model.task.task_id,
        base_instruction=model.task.language,
        instruction=draft.instruction,
        family="spatial",
        level=draft.level,
        factors=draft.factors,
        premise=draft.premise,
        witness=draft.witness,
        status="accepted",
        init_states=draft.init_states,
    )
    return not (check_structure(case, "false_relation", model) or check_relation(case, model, states))


OPERATORS = [("spatial.false_relation", "spatial", generate)]
