"""Words for things: how scene entities and regions are named, and which referents are absent.

A grounding conflict names something the scene does not hold. "Absent" is decided here, against
the scene's whole vocabulary: every name, synonym and hypernym of every object and fixture in the
base task (from the affordance table), every near-synonym and part a reader could take to denote
it (the checked synonym table, ``data/synonyms.jsonl``: basket -> bucket, pail, crate, colander ...;
stove -> cooktop, burner, hob ...; cabinet -> drawer, cupboard, dresser ...), the head nouns of
their names, the names of its regions, and the words any scene has (the robot, its gripper, the
table). A referent is absent only if neither its phrase, nor any of its synonyms, nor their head
nouns is in that vocabulary, and none of its content words is a word of a present thing's name
("orange soda" next to the orange juice is refused: too close to call).

A WRONG ATTRIBUTE ("the red bowl" where the only bowls are black) is the one referent that shares
its head noun with something present. ``data/attributes.jsonl`` gives the visible colour of each
LIBERO category whose colour is unambiguous (wooden things are recorded as "wood", whose tones read
as yellow, orange, tan, beige, brown or gold); a wrong colour is one of :data:`COLOURS` that is not,
and is not close to (:func:`close_colours`, either way round), the colour of ANY attribute-known
thing in the scene, nor a word of any present name; and every present thing the noun could denote
has a known colour (otherwise "the red X" could be a thing whose colour the table does not know).
Against black, white and wood that leaves red, blue, green, purple and pink.
"""

from __future__ import annotations

import functools
import json
import re
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from conflictbench.tasks.libero.bddl import BDDLProblem
from conflictbench.tasks.scene.affordances import AffordanceTableError, category, load_table

ABSENT_TABLE = "absent_referents.jsonl"
SYNONYM_TABLE = "synonyms.jsonl"
ATTRIBUTE_TABLE = "attributes.jsonl"
ROLES = ("object", "support", "container", "appliance", "openable")
COLOURS = ("red", "blue", "green", "yellow", "orange", "purple", "pink", "white", "black")
NEAR_COLOURS = {
    "red": {"pink", "orange", "maroon"},
    "pink": {"red", "purple"},
    "orange": {"red", "yellow", "brown"},
    "yellow": {"orange", "cream", "gold"},
    # a light ceramic can look cream, and cream reads as pale yellow
    "white": {"cream", "grey", "silver", "beige", "yellow"},
    "black": {"grey", "brown", "dark"},
    "brown": {"orange", "black", "wooden", "beige", "yellow", "tan", "gold"},
    # wood tones read as yellow, orange, tan, beige, brown or gold, depending on the grain and light
    "wood": {"yellow", "orange", "tan", "beige", "brown", "gold", "wooden"},
    "grey": {"silver", "white", "black"},
    "blue": {"purple"},
    "purple": {"blue", "pink"},
    "green": set(),
}
"""Colours a reader could confuse (the relation is read both ways by :func:`close_colours`): a wrong
attribute is never one of these next to a present colour."""


def close_colours(colour: str) -> set[str]:
    """The colour and every colour a reader could take it for, either way round ("yellow" is close to
    "wood" because wood is listed close to yellow)."""
    return {colour} | NEAR_COLOURS.get(colour, set()) | {c for c, near in NEAR_COLOURS.items() if colour in near}


SCENE_WORDS = (
    "robot",
    "robot arm",
    "arm",
    "gripper",
    "hand",
    "table",
    "floor",
    "wall",
    "scene",
    "object",
    "item",
    "thing",
    "drawer",
    "door",
    "handle",
    "knob",
    "lid",
    "top",
    "compartment",
    "region",
    "side",
)
STOPWORDS = {"the", "a", "an", "of", "and", "pair", "set", "piece", "with", "small", "big", "large"}
_WORD = re.compile(r"[a-z]+")


@dataclass(frozen=True)
class AbsentConcept:
    concept: str
    phrase: str
    synonyms: tuple[str, ...]
    roles: tuple[str, ...]
    size: int
    """The affordance table's size class (1 hand-sized .. 4 furniture): what can go in or on it."""


@dataclass(frozen=True)
class Colouring:
    """A LIBERO category's visible colour(s), and the noun its colour is said with ("bowl")."""

    category: str
    noun: str
    colours: tuple[str, ...]


def words(text: str) -> list[str]:
    return _WORD.findall(text.lower())


def content_words(text: str) -> set[str]:
    return {w for w in words(text) if w not in STOPWORDS}


@functools.cache
def absent_concepts(path: str | None = None) -> tuple[AbsentConcept, ...]:
    p = Path(path) if path else _data(ABSENT_TABLE)
    out = []
    for number, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        try:
            row = json.loads(line)
            concept = AbsentConcept(
                row["concept"], row["phrase"], tuple(row["synonyms"]), tuple(row["roles"]), int(row["size"])
            )
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise AffordanceTableError(
                f"{p} line {number}: malformed absent referent ({type(exc).__name__}: {exc})"
            ) from None
        unknown = set(concept.roles) - set(ROLES)
        if unknown:
            raise AffordanceTableError(
                f"{p} line {number}, field 'roles': unknown {sorted(unknown)}; valid: {', '.join(ROLES)}"
            )
        out.append(concept)
    return tuple(out)


def concept(name: str) -> AbsentConcept | None:
    return next((c for c in absent_concepts() if c.concept == name), None)


def _data(name: str) -> Path:
    return Path(str(resources.files("conflictbench.tasks") / "data" / name))


def _rows(name: str, keys: tuple[str, ...]) -> list[dict]:
    p = _data(name)
    out = []
    for number, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        try:
            row = json.loads(line)
            missing = [k for k in keys if k not in row]
        except json.JSONDecodeError as exc:
            raise AffordanceTableError(f"{p} line {number}: not valid JSON ({exc.msg})") from None
        if missing:
            raise AffordanceTableError(f"{p} line {number}: missing field(s) {missing}")
        out.append(row)
    return out


@functools.cache
def near_synonyms() -> dict[str, tuple[str, ...]]:
    """Category -> every near-synonym and part a reader could take to denote it (synonyms.jsonl)."""
    return {
        r["category"]: tuple(r["near_synonyms"]) + tuple(r["parts"])
        for r in _rows(SYNONYM_TABLE, ("category", "near_synonyms", "parts"))
    }


@functools.cache
def colourings() -> dict[str, Colouring]:
    """Category -> its visible colour(s), for the categories whose colour is unambiguous (attributes.jsonl)."""
    rows = _rows(ATTRIBUTE_TABLE, ("category", "noun", "colours", "note"))
    return {r["category"]: Colouring(r["category"], r["noun"], tuple(r["colours"])) for r in rows}


def denotations(cat: str) -> set[str]:
    """Every phrase that may denote a thing of the category: names, synonyms, hypernyms, near-synonyms,
    parts, and the head nouns of its names."""
    info = category(cat)
    out = set(info.names) | set(info.synonyms) | set(info.hypernyms) | set(near_synonyms().get(cat, ()))
    return out | {head(n) for n in info.names}


def head(phrase: str) -> str:
    w = words(phrase)
    return w[-1] if w else phrase


# -- regions --------------------------------------------------------------------------------------
_SIDE = re.compile(r"_(back|front|left|right)_contain_region$")
_LEVEL = re.compile(r"_(top|middle|bottom)_region$")


def region_phrase(region: str, parent: str, parent_category: str) -> tuple[str, str]:
    """``(preposition, noun phrase)`` for a BDDL region used as a destination.

    Raises ``KeyError`` for a region without a fixed English name (most table regions): those
    are only ever named through the objects near them.
    """
    parent_name = category(parent_category).name if parent_category in load_table() else parent
    drawer_holder = "cabinet" in parent_category
    if region.endswith("_cook_region"):
        return "on", f"the {parent_name}"
    if region.endswith("_top_side"):
        return "on", f"top of the {parent_name}"
    if drawer_holder and _LEVEL.search(region):
        return "in", f"the {_LEVEL.search(region).group(1)} drawer of the {parent_name}"
    if region.endswith("_top_region"):
        return "on", f"the {parent_name}"
    if _SIDE.search(region):
        return "in", f"the {_SIDE.search(region).group(1)} compartment of the {parent_name}"
    if region.endswith("_contain_region") or region.endswith("_heating_region"):
        return "in", f"the {parent_name}"
    raise KeyError(region)


def region_names(region: str, parent_category: str | None) -> list[str]:
    """Words a text may use for a region: its own noun ("top drawer") and its holder's names."""
    out = []
    level = _LEVEL.search(region)
    if level and parent_category and "cabinet" in parent_category:
        out += [f"{level.group(1)} drawer", "drawer"]
    side = _SIDE.search(region)
    if side:
        out += [f"{side.group(1)} compartment", "compartment"]
    if region.endswith("_top_side"):
        out += ["top"]
    if parent_category and parent_category in load_table():
        out += list(category(parent_category).names)
    return out


# -- scene vocabulary -----------------------------------------------------------------------------
def scene_categories(problem: BDDLProblem) -> list[str]:
    return sorted(set(problem.objects.values()) | set(problem.fixtures.values()))


def scene_vocabulary(problem: BDDLProblem) -> tuple[set[str], set[str]]:
    """(phrases, name words) of everything present in the base task's scene."""
    phrases: set[str] = set(SCENE_WORDS)
    name_words: set[str] = set()
    for cat in scene_categories(problem):
        info = category(cat)
        phrases |= denotations(cat)
        for phrase in (*info.names, *info.synonyms):
            name_words |= content_words(phrase)
    for region in problem.regions.values():
        parent_cat = problem.fixtures.get(region.target) or problem.objects.get(region.target)
        phrases |= set(region_names(region.name, parent_cat))
    return phrases, name_words


def absence_problem(phrase: str, synonyms: Iterable[str], problem: BDDLProblem) -> str | None:
    """Why ``phrase`` may denote something in the scene, or ``None`` when it is truly absent."""
    phrases, name_words = scene_vocabulary(problem)
    for candidate in (phrase, *synonyms):
        c = candidate.lower()
        if c in phrases:
            return f"{candidate!r} names something in the scene"
        head = words(c)[-1] if words(c) else c
        if head in phrases:
            return f"{candidate!r} is a kind of {head!r}, which is in the scene"
    shared = content_words(phrase) & name_words
    if shared:
        return f"{phrase!r} shares the word(s) {', '.join(sorted(shared))} with something in the scene"
    return None


def receptacle_words(problem: BDDLProblem) -> set[str]:
    """Words a reader could map onto an OPEN receptacle present (basket, caddy, bowl, mug ...): its
    denotations, with the receptacle words of synonyms.jsonl ("bucket" for the desk caddy)."""
    out: set[str] = set()
    for cat in scene_categories(problem):
        info = category(cat)
        if info.has("container") is True and info.has("openable") is False:
            out |= denotations(cat)
    return out


def receptacle_problem(phrase: str, synonyms: Iterable[str], problem: BDDLProblem) -> str | None:
    """Why ``phrase`` as a receptacle could be read as an open receptacle present, else ``None``."""
    taken = receptacle_words(problem)
    for candidate in (phrase, *synonyms):
        c = candidate.lower()
        if c in taken or (words(c) and words(c)[-1] in taken):
            return f"a reader could take {candidate!r} for an open receptacle in the scene"
    return None


def absent_for(problem: BDDLProblem, role: str) -> list[AbsentConcept]:
    """The out-of-domain absent referents usable in ``role`` for this scene, in table order."""
    return [c for c in absent_concepts() if role in c.roles and absence_problem(c.phrase, c.synonyms, problem) is None]


SCENERY = {"table", "kitchen_table", "living_room_table", "study_table", "floor"}
"""Categories every scene has in some form: never an absent LIBERO referent."""


def libero_absent(problem: BDDLProblem) -> list[str]:
    """LIBERO categories absent from this scene that share no word a reader could confuse with
    anything present (no "white bowl" beside a black bowl: that is a wrong attribute)."""
    present = set(scene_categories(problem))
    return [
        cat
        for cat, info in load_table().items()
        if cat not in present and cat not in SCENERY and absence_problem(info.name, info.synonyms, problem) is None
    ]


def _instances(noun: str, problem: BDDLProblem) -> list[str]:
    """Present categories the noun could denote (a ramekin is a bowl too)."""
    out = []
    for cat in scene_categories(problem):
        info = category(cat)
        if noun in denotations(cat) or noun in {head(n) for n in (*info.names, *info.synonyms)}:
            out.append(cat)
    return out


def wrong_colours(noun: str, problem: BDDLProblem) -> list[str]:
    """Colours that make "<colour> <noun>" a wrong attribute here; none when the noun denotes
    nothing present or something of unknown colour."""
    known = colourings()
    instances = _instances(noun, problem)
    if not instances or any(c not in known for c in instances):
        return []
    taken: set[str] = set()
    for cat in scene_categories(problem):
        if cat in known:
            for colour in known[cat].colours:
                taken |= close_colours(colour)
        taken |= {w for phrase in (*category(cat).names, *category(cat).synonyms) for w in words(phrase)}
    return [c for c in COLOURS if c not in taken]


def attribute_problem(phrase: str, problem: BDDLProblem) -> str | None:
    """Why ``phrase`` ("red bowl") is not a wrong attribute of something present, or ``None``."""
    colour, _, noun = phrase.partition(" ")
    if colour not in COLOURS:
        return f"{colour!r} is not a colour of the attribute table"
    if not _instances(noun, problem):
        return f"nothing in the scene is a {noun!r}: not a wrong attribute"
    if colour not in wrong_colours(noun, problem):
        return (
            f"{phrase!r} may denote something in the scene (a {noun} of that or a close colour, or of unknown colour)"
        )
    phrases, _ = scene_vocabulary(problem)
    if phrase in phrases:
        return f"{phrase!r} names something in the scene"
    return None


def with_article(noun_phrase: str) -> str:
    return noun_phrase if noun_phrase.startswith("the ") else f"the {noun_phrase}"
