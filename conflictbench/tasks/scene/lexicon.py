"""Words for things: how scene entities and regions are named, and which referents are absent.

A grounding conflict names something the scene does not hold. "Absent" is decided here, against
the scene's whole vocabulary: every name, synonym and hypernym of every object and fixture in the
base task (from the affordance table), the names of its regions, and the words any scene has (the
robot, its gripper, the table). A referent is absent only if neither its phrase, nor any of its
synonyms, nor its head noun is in that vocabulary, and none of its content words is a word of a
present thing's name ("orange soda" next to the orange juice is refused: too close to call).
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
ROLES = ("object", "support", "container", "appliance", "openable", "landmark")
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


def words(text: str) -> list[str]:
    return _WORD.findall(text.lower())


def content_words(text: str) -> set[str]:
    return {w for w in words(text) if w not in STOPWORDS}


@functools.cache
def absent_concepts(path: str | None = None) -> tuple[AbsentConcept, ...]:
    p = Path(path) if path else Path(str(resources.files("conflictbench.tasks") / "data" / ABSENT_TABLE))
    out = []
    for number, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        try:
            row = json.loads(line)
            concept = AbsentConcept(row["concept"], row["phrase"], tuple(row["synonyms"]), tuple(row["roles"]))
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
        phrases |= set(info.names) | set(info.synonyms) | set(info.hypernyms)
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


def absent_for(problem: BDDLProblem, role: str) -> list[AbsentConcept]:
    """The absent referents usable in ``role`` for this scene, in table order."""
    return [c for c in absent_concepts() if role in c.roles and absence_problem(c.phrase, c.synonyms, problem) is None]


def with_article(noun_phrase: str) -> str:
    return noun_phrase if noun_phrase.startswith("the ") else f"the {noun_phrase}"
