"""Spatial operators: a relational description that is false in the initial scene.

Every entity stays present and named; what breaks is the relation the words presuppose ("the
ketchup to the left of the basket" where the ketchup starts to its right, "the black bowl on the
cookie box" where no bowl touches the box). A claim is about every entity the subject's words could
pick out (both black bowls of a libero_spatial scene), and must be false for all of them, under
the lenient reading of :meth:`.scene.TaskFacts.holds`, in every fixed initial state the case is
paired with: all 50 where possible, otherwise the listed states (at least ``MIN_STATES``).
"""

from __future__ import annotations

import itertools
import random

from conflictbench.tasks.scene.affordances import category
from conflictbench.tasks.scene.task_model import TaskModel

from .frames import Draft, Mods, Slot, frame_witness, frames_for_level, realise, step_label
from .phrasing import bare, choose

MIN_STATES = 25
"""A claim false in fewer of the 50 initial states is not used (the case would pair too rarely)."""
PHRASES = {
    "left_of": ("to the left of", "on the left side of", "left of"),
    "right_of": ("to the right of", "on the right side of", "right of"),
    "in_front_of": ("in front of",),
    "behind": ("behind",),
    "next_to": ("next to", "beside", "right next to"),
    "on": ("on", "on top of", "sitting on", "resting on"),
    "in": ("in", "inside"),
    "between": ("between",),
}
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


def subject_noun(model: TaskModel, entity: str) -> tuple[str, list[str]]:
    """The plain noun phrase for an entity and every entity it could denote.

    An entity whose name carries the base task's own relation ("the black bowl between the plate
    and the ramekin") is called by its category's noun, which then covers its twin as well.
    """
    name = model.name(entity)
    noun = f"the {category(model.category_of(entity)).names[0]}"
    phrase = noun if entity in model.goal_twins() else name
    return phrase, sorted(model.candidates(phrase))


def _short(model: TaskModel, entity: str) -> str:
    """A landmark's words: twins go by their plain noun (the claim then covers both)."""
    if entity in model.goal_twins():
        return f"the {category(model.category_of(entity)).names[0]}"
    return model.name(entity)


def _landmarks(model: TaskModel, relation: str, subject: str, exclude: set[str]) -> list[tuple[str, str]]:
    """(entity, noun phrase) usable as the relation's landmark for ``subject``.

    "on" needs a real support and "in" a container at least as large as the subject: "the bowl on
    the ketchup" would be absurd rather than false.
    """
    out = []
    size = category(model.category_of(subject)).size if model.category_of(subject) != "region" else 4
    if relation in ("on", "in"):
        for ent, (prep, np_) in model.dest_phrases.items():
            holder_name = model.parent(ent)
            if ent in exclude or holder_name in exclude or ent in model.unnamed or not np_.startswith("the "):
                continue
            if ent not in model.facts.entities:
                continue
            holder = category(model.category_of(holder_name))
            if holder.size < size:
                continue
            if (
                relation == "on" and prep == "on" and holder.has("support") is True and ent not in model.fixtures()
            ) or (relation == "in" and prep == "in" and holder.has("container")):
                out.append((ent, _short(model, ent) if ent in model.names else np_))
        return out
    for ent in model.names:
        if ent not in exclude and ent not in model.unnamed and ent in model.facts.entities:
            out.append((ent, _short(model, ent)))
    return out


def claims(model: TaskModel, subject: str, avoid: frozenset = frozenset()) -> list[dict]:
    """Every false relation about ``subject``, with the states where it is false for all candidates.

    ``avoid``: entities the same step already acts on (the moved object, the destination), which
    would make a landmark read oddly ("the plate next to the bowl" while moving that bowl).
    """
    noun, candidates = subject_noun(model, subject)
    movable = model.facts.entities[subject].kind == "object"
    out = []
    for relation in PHRASES:
        if relation in ("on", "in") and not movable:
            continue
        exclude = (
            set(candidates) | {model.parent(c) for c in candidates} | set(avoid) | {model.parent(a) for a in avoid}
        )
        marks = [
            np_ for _, np_ in _landmarks(model, "next_to" if relation == "between" else relation, subject, exclude)
        ]
        options = [list(p) for p in itertools.combinations(marks, 2)] if relation == "between" else [[m] for m in marks]
        for phrases in options:
            if relation in ("left_of", "right_of") and any(
                w in f" {p} " for p in (noun, *phrases) for w in (" left ", " right ")
            ):
                continue  # "the left plate to the right of ..." reads as a contradiction in words, not a false relation
            groups = [sorted(model.candidates(p)) for p in phrases]
            if not all(groups) or any(set(g) & set(candidates) for g in groups):
                continue
            false = model.facts.states()
            for cand in candidates:
                for combo in itertools.product(*groups):
                    if len(set(combo)) == len(combo):
                        false = false & model.facts.false_states(relation, cand, *combo)
            if len(false) >= MIN_STATES:
                out.append(
                    {
                        "relation": relation,
                        "subject": noun,
                        "candidates": candidates,
                        "landmark_phrases": phrases,
                        "landmark_text": " and ".join(phrases),
                        "false_states": false,
                    }
                )
    return out


def _subject_of(model: TaskModel, slot: Slot, part: str) -> str | None:
    if part == "object":
        return (
            slot.objects[0] if len(slot.objects) == 1 and slot.kind in ("place", "push", "pick", "move_aside") else None
        )
    if part == "dest" and slot.dest and slot.kind in ("place", "place_it", "push"):
        holder = model.parent(slot.dest)
        return holder if holder in model.names and holder in model.facts.entities else None
    if part == "target" and slot.kind in ("open", "close", "turn_on", "turn_off"):
        holder = model.parent(slot.objects[0])
        return holder if holder in model.names and holder in model.facts.entities else None
    return None


def _phrase(claim: dict, rng: random.Random, clause: bool = False) -> str:
    """ "the bowl behind the stove"; with ``clause`` always a relative clause ("the bowl that is
    behind the stove"), where a bare modifier could be read as a destination (push X behind Y)."""
    rel = choose(rng, PHRASES[claim["relation"]])
    if rel.startswith(("sitting", "resting")):
        form = "{s} {r} {l}"
    else:
        form = "{s} that is {r} {l}" if clause else choose(rng, ("{s} {r} {l}", "{s} that is {r} {l}", "{s} {r} {l}"))
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
    text = _phrase(claim, rng, clause=part == "object" and slot.kind != "place")
    if part == "object":
        mods.locating = True
    if part in ("object", "target"):
        if part == "target" and slot.objects[0] != model.parent(slot.objects[0]):
            # a drawer: "the top drawer of the cabinet that is next to the stove"
            np_ = model.dest_phrases[slot.objects[0]][1]
            mods.obj = np_.replace(model.name(model.parent(slot.objects[0])), text)
        else:
            mods.obj = text
        return text
    prep, np_ = model.dest_phrases[slot.dest]
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


def generate(model: TaskModel, level: str, rng: random.Random):
    cache: dict[tuple, list[dict]] = {}

    def claims_for(entity: str, avoid: frozenset) -> list[dict]:
        if (entity, avoid) not in cache:
            cache[(entity, avoid)] = claims(model, entity, avoid)
        return cache[(entity, avoid)]

    for frame in frames_for_level(model, level):
        parts = [
            (i, p) for i, slot in enumerate(frame) for p in ("object", "dest", "target") if _subject_of(model, slot, p)
        ]
        if level in ("L1", "L3"):
            combos = [[p] for p in parts]
        elif level == "L2":  # two parts of one step, or two claims about one part
            combos = [list(c) for c in itertools.combinations(parts, 2) if c[0][0] == c[1][0]] + [[p, p] for p in parts]
        else:
            combos = [list(c) for c in itertools.combinations(parts, 2) if c[0][0] != c[1][0]]
        for combo in combos:
            for _ in range(3):
                draft = _draft(model, level, frame, combo, claims_for, rng)
                if draft:
                    yield draft


def _draft(model, level, frame, combo, claims_for, rng: random.Random) -> Draft | None:
    mods: dict[int, Mods] = {}
    chosen = []
    states = model.facts.states()
    for index, part in combo:
        slot = frame[index]
        subject = _subject_of(model, slot, part)
        avoid = frozenset(e for e in (*slot.objects, slot.dest) if e and e != subject)
        pool = [c for c in claims_for(subject, avoid) if len(c["false_states"] & states) >= MIN_STATES]
        if not pool:
            return None
        earlier = next((t for i, p, c, t in chosen if (i, p) == (index, part)), None)
        if earlier:
            first = next(c for i, p, c, t in chosen if (i, p) == (index, part))
            pool = [
                c
                for c in pool
                if c["relation"] != first["relation"]
                and c["landmark_text"] != first["landmark_text"]
                and c["relation"] not in ("between", "on", "in")
                and first["relation"] != "between"
            ]
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
    relations = [
        {
            "step": i + 1,
            "text": text,
            "relation": c["relation"],
            "subject": {"phrase": bare(c["subject"]), "entities": sorted(c["candidates"])},
            "landmarks": [{"phrase": bare(p), "entities": sorted(model.candidates(p))} for p in c["landmark_phrases"]],
        }
        for i, part, c, text in chosen
    ]
    return Draft(
        family="spatial",
        level=level,
        instruction=instruction,
        factors=tuple(
            step_label(level, i, f"{part} relation ({c['relation'].replace('_', ' ')})") for i, part, c, _ in chosen
        ),
        premise="; ".join(_premise(model, c) for _, _, c, _ in chosen),
        witness={"type": "false_relation", **frame_witness(model, frame, steps), "relations": relations},
        init_states=None if states == model.facts.states() else tuple(sorted(states)),
        operator="spatial.false_relation",
    )


OPERATORS = [("spatial.false_relation", "spatial", generate)]
