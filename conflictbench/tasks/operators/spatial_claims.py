"""Claim finding of the spatial operators: every false relation that can be said about an entity.

Kept apart from :mod:`.spatial`, which places claims into a task's steps, writes and checks the
case, because finding them is a self-contained search over the scene facts (the subject's possible
referents, the landmarks allowed for each relation, the initial states where the relation is false
for all of them) with no knowledge of frames or wording beyond the relation phrases.
"""

from __future__ import annotations

import itertools

from conflictbench.tasks.scene.affordances import category
from conflictbench.tasks.scene.facts import DIRECTIONS
from conflictbench.tasks.scene.task_model import TaskModel
from conflictbench.tasks.validation.spatial import MIN_STATES, SAME_AXIS_WORDS, has_own_front, same_kind_pair

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
"""The relations a claim may state, in the order they are tried, and the ways each is worded."""


def subject_noun(model: TaskModel, entity: str) -> tuple[str, list[str]]:
    """The noun phrase for an entity and every entity it could denote (never a twinned bowl: the
    operator makes no claim about one)."""
    name = model.name(entity)
    return name, sorted(model.candidates(name))


def _is_twin(model: TaskModel, entity: str) -> bool:
    """Whether ``entity`` (or its holder) has an identical twin: its bare noun would denote both,
    and its full name ("the black bowl next to the ramekin") buried inside another thing's
    description reads as a tangle, so a twin is never a landmark."""
    return bool({entity, model.parent(entity)} & (model.goal_twins() | model.unnamed))


def _landmarks(model: TaskModel, relation: str, subject: str, exclude: set[str]) -> list[tuple[str, str]]:
    """(entity, noun phrase) usable as the relation's landmark for ``subject``.

    "on" needs a real support and "in" a container at least as large as the subject: "the bowl on
    the ketchup" would be absurd rather than false.
    """
    if relation in ("on", "in"):
        return _holders(model, relation, subject, exclude)
    out = []
    for ent in model.names:
        if ent not in exclude and not _is_twin(model, ent) and ent in model.facts.entities:
            if relation in DIRECTIONS and has_own_front(model, ent):
                continue  # "in front of the cabinet": its drawers' side or the camera's? Readers split.
            out.append((ent, model.name(ent)))
    return out


def _holders(model: TaskModel, relation: str, subject: str, exclude: set[str]) -> list[tuple[str, str]]:
    """The landmarks of "on" (a real support) and "in" (a container), at least as large as ``subject``."""
    out = []
    size = category(model.category_of(subject)).size if model.category_of(subject) != "region" else 4
    for ent, (prep, np_) in model.dest_phrases.items():
        holder_name = model.parent(ent)
        if ent in exclude or holder_name in exclude or _is_twin(model, ent) or not np_.startswith("the "):
            continue
        if ent not in model.facts.entities:
            continue
        if relation == "in" and "drawer" in np_:
            continue  # a closed drawer hides its contents: "the plate inside the drawer" cannot be seen false
        holder = category(model.category_of(holder_name))
        if holder.size < size:
            continue
        if (relation == "on" and prep == "on" and holder.has("support") is True and ent not in model.fixtures()) or (
            relation == "in" and prep == "in" and holder.has("container")
        ):
            out.append((ent, model.name(ent) if ent in model.names else np_))
    return out


def claims(model: TaskModel, subject: str, avoid: frozenset = frozenset(), holder_avoid: frozenset = frozenset()):
    """Every false relation about ``subject``, with the states where it is false for all candidates.

    ``avoid``: entities no landmark may be (moved by this step or an earlier one, which would make
    the claim stale or read oddly); ``holder_avoid``: entities no "on"/"in" holder may be (the
    step's own destination: "pick up the sauce in the basket, then put it in the basket").
    """
    noun, candidates = subject_noun(model, subject)
    movable = model.facts.entities[subject].kind == "object"
    out = []
    for relation in PHRASES:
        if relation in ("on", "in", "between") and not movable:
            continue  # "the cabinet between the bowl and the plate" reads oddly; fixtures sit on nothing
        exclude = set(candidates) | {model.parent(c) for c in candidates} | set(avoid)
        if relation in ("on", "in"):
            exclude |= set(holder_avoid)
        kind = "next_to" if relation == "between" else relation
        marks = [np_ for ent, np_ in _landmarks(model, kind, subject, exclude) if model.parent(ent) not in exclude]
        options = [list(p) for p in itertools.combinations(marks, 2)] if relation == "between" else [[m] for m in marks]
        for phrases in options:
            groups = _landmark_groups(model, relation, subject, noun, candidates, phrases, exclude)
            if groups is None:
                continue
            false = _false_for_all(model, relation, candidates, groups)
            if len(false) >= MIN_STATES:
                out.append(
                    {
                        "relation": relation,
                        "subject": noun,
                        "candidates": candidates,
                        "landmark_phrases": phrases,
                        "landmark_groups": groups,
                        "landmark_text": " and ".join(phrases),
                        "false_states": false,
                    }
                )
    return out


def _landmark_groups(model, relation: str, subject: str, noun: str, candidates: list[str], phrases, exclude):
    """What each landmark phrase could denote, or None when the claim cannot be said with these phrases: a word
    of the relation's own axis in a name, a phrase denoting nothing or the subject, an excluded landmark, or a
    pair of like things side by side."""
    axis_words = SAME_AXIS_WORDS.get(relation, ())
    if any(w in f" {p} ".split() for p in (noun, *phrases) for w in axis_words):
        return None  # "the left plate to the right of ..." reads as a contradiction in words
    groups = [sorted(model.candidates(p)) for p in phrases]
    if not all(groups) or any(set(g) & set(candidates) for g in groups):
        return None
    if any(e in exclude or model.parent(e) in exclude for g in groups for e in g):
        return None
    if relation == "next_to" and same_kind_pair(model, subject, groups[0]):
        return None  # "the right plate beside the left plate": a pair reads as side by side at any gap
    return groups


def _false_for_all(model: TaskModel, relation: str, candidates: list[str], groups: list[list[str]]) -> frozenset:
    """The initial states where the relation is false for every subject candidate and distinct landmarks."""
    false = model.facts.states()
    for cand in candidates:
        for combo in itertools.product(*groups):
            if len(set(combo)) == len(combo):
                false = false & model.facts.false_states(relation, cand, *combo)
    return false


def _names(model: TaskModel, entity: str) -> set[str]:
    """Names of ``entity`` that denote it alone (or with its holder); also used by :mod:`.spatial`."""
    return {n for n in model.entity_names(entity) if model.candidates(n) <= {entity, model.parent(entity)}}
