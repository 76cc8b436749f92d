"""The pipeline's first steps: a base task as entities and ordered steps, ready for the operators.

A :class:`TaskModel` joins a base task's BDDL problem (objects, fixtures, regions, goal), its scene
facts (what holds in the 50 fixed initial states) and the lexicon (how things are called). Its
``steps`` are the base task's subgoals in the order the reference instruction gives them
(``put both X and Y in the basket`` is one step with two objects; ``open the top drawer and put
the bowl inside`` is two, the opening being implied by a goal inside a closed drawer).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from conflictbench.tasks.libero.base_tasks import BaseTask
from conflictbench.tasks.scene.affordances import category, load_table
from conflictbench.tasks.scene.facts import TaskFacts
from conflictbench.tasks.scene.lexicon import region_names, region_phrase

IN_THE_WAY_GAP = 0.10
"""An added "move X out of the way" is true only where X's footprint comes within this of what the
task moves or of its destination (the "next to" distance of the scene facts): suite 2.0's readers
found "move the cookie box out of the way" with the box 16-25 cm from anything the task touches."""
STATE_KINDS = {"open": "open", "close": "close", "turnon": "turn_on", "turnoff": "turn_off"}
_TABLE_REGION = re.compile(r"^(?P<landmark>[a-z]+(?:_[a-z]+)*?)_(?P<side>left|right|front|back)_region$")
_SIDES = {"right": "to the right of", "left": "to the left of", "front": "to the front of", "back": "behind"}


@dataclass(frozen=True)
class Step:
    """One subgoal: what is done to which entities, and the BDDL literals it achieves."""

    kind: str
    """``place`` | ``push`` | ``pick`` | ``open`` | ``close`` | ``turn_on`` | ``turn_off``."""
    objects: tuple[str, ...]
    """The moved objects (place/push/pick) or the operated fixture or region (state steps)."""
    dest: str | None = None
    prep: str | None = None
    goal: tuple[tuple[str, ...], ...] = ()


@dataclass
class TaskModel:
    task: BaseTask
    facts: TaskFacts
    names: dict[str, str] = field(default_factory=dict)
    """Entity -> its noun phrase with article ("the black bowl", "the left plate")."""
    steps: list[Step] = field(default_factory=list)
    dest_phrases: dict[str, tuple[str, str]] = field(default_factory=dict)
    """Destination entity or region -> (preposition, noun phrase)."""
    unnamed: set[str] = field(default_factory=set)
    """Entities that have no unambiguous name (the second of two identical bowls)."""

    @property
    def problem(self):
        return self.task.problem

    def category_of(self, entity: str) -> str:
        e = self.facts.entities.get(entity)
        if e is not None and e.kind != "region":
            return e.category
        return self.problem.objects.get(entity) or self.problem.fixtures.get(entity) or "region"

    def parent(self, entity: str) -> str:
        e = self.facts.entities.get(entity)
        return e.parent if e is not None and e.kind == "region" and e.parent else entity

    def name(self, entity: str) -> str:
        return self.names[entity]

    def dest_text(self, dest: str, prep: str | None = None) -> str:
        """The destination as a prepositional phrase: "on the plate", "to the right of the plate"."""
        p, np_ = self.dest_phrases[dest]
        p = p if prep is None or not p else prep
        return f"{p} {np_}".strip()

    def objects(self) -> list[str]:
        return [n for n in self.problem.objects if n in self.names]

    def fixtures(self) -> list[str]:
        return [n for n in self.problem.fixtures if n in self.names]

    def targets(self) -> set[str]:
        return {o for s in self.steps for o in s.objects} | {s.dest for s in self.steps if s.dest}

    def entity_names(self, entity: str) -> set[str]:
        """Every phrase a text may use for the entity (its name, its category's names and synonyms)."""
        if entity == "robot":
            return {"robot", "arm", "gripper"}
        out = set()
        if entity in self.names:
            out.add(self.names[entity].removeprefix("the "))
        cat = self.category_of(entity)
        if cat in load_table():
            out |= set(category(cat).names) | set(category(cat).synonyms)
        if entity in self.dest_phrases:
            out.add(self.dest_phrases[entity][1].removeprefix("the "))
        e = self.facts.entities.get(entity)
        if e is not None and e.kind == "region":
            out |= set(region_names(entity, self.category_of(self.parent(entity))))
        return {n for n in out if n}

    def candidates(self, phrase: str) -> set[str]:
        """Every entity of the scene the phrase could denote (both black bowls for "black bowl")."""
        key = " ".join(phrase.lower().removeprefix("the ").split())
        return {e for e in self.facts.entities if key in self.entity_names(e)}

    def goal_twins(self) -> set[str]:
        """Named entities with an unnamed twin: their name holds the base task's own relation."""
        twins = {self.category_of(e) for e in self.unnamed}
        return {e for e in self.names if self.category_of(e) in twins}

    def in_the_way(self, entity: str, states: frozenset | None = None) -> bool:
        """Could moving the entity "out of the way" be true: is its footprint within
        :data:`IN_THE_WAY_GAP` of a thing the base task moves, or of where it goes, in every state?"""
        near = [
            t
            for t in {self.parent(t) for t in self.targets()}
            if t != entity and t in self.facts.entities and self.facts.entities[t].kind != "region"
        ]
        idx = sorted(states if states is not None else self.facts.states())
        if not near or not idx:
            return False
        gaps = np.min([self.facts.footprint_distance(entity, t)[idx] for t in near], axis=0)
        return bool((gaps <= IN_THE_WAY_GAP).all())

    def always(self, *atom: str) -> bool:
        return self.facts.predicate(*atom) == self.facts.states()

    def never(self, *atom: str) -> bool:
        return not self.facts.predicate(*atom)


def _base_modifier(language: str, noun: str) -> str | None:
    m = re.search(rf"the {re.escape(noun)} (.+?) and (?:place|put)", language)
    return m.group(1) if m else None


def _init_side(problem, entity: str) -> str | None:
    for atom in problem.init:
        if len(atom) == 3 and atom[0] == "on" and atom[1] == entity:
            m = re.search(r"_(left|right)_", atom[2] + "_")
            if m:
                return m.group(1)
    return None


def _name_entities(model: TaskModel) -> None:
    problem, language = model.problem, model.task.language
    by_category: dict[str, list[str]] = {}
    for name, cat in [*problem.objects.items(), *problem.fixtures.items()]:
        by_category.setdefault(cat, []).append(name)
    goal_entities = {a for atom in problem.goal for a in atom[1:]}
    shared: dict[str, int] = {}
    for cat in by_category:
        for n in category(cat).names:
            shared[n] = shared.get(n, 0) + 1
    for cat, members in by_category.items():
        info = category(cat)
        own = [n for n in info.names if shared[n] == 1] or list(info.names)  # "mug" names three mugs
        # The reference instruction's own word wins ("cream cheese box" in libero_10, "bowl" in libero_goal).
        said = [n for n in own if re.search(rf"\b{re.escape(n)}\b", language)]
        noun = max(said, key=len) if said else own[0]
        if len(members) == 1:
            model.names[members[0]] = f"the {noun}"
            continue
        for member in members:
            side = _init_side(problem, member)
            if side:
                model.names[member] = f"the {side} {noun}"
            elif member in goal_entities and _base_modifier(language, noun):
                model.names[member] = f"the {noun} {_base_modifier(language, noun)}"
            else:
                model.unnamed.add(member)


def _dest_phrases(model: TaskModel) -> None:
    problem = model.problem
    for name in model.names:
        model.dest_phrases[name] = ("on", model.names[name])
    for region in problem.regions.values():
        if region.name not in model.facts.entities:
            continue
        parent_cat = problem.fixtures.get(region.target) or problem.objects.get(region.target)
        if parent_cat and parent_cat in load_table() and region.target in model.names:
            try:
                prep, noun = region_phrase(region.name, region.target, parent_cat)
                noun = noun.replace(f"the {category(parent_cat).name}", model.names[region.target])
                model.dest_phrases[region.name] = (prep, noun)
                continue
            except KeyError:
                pass
        short = region.name[len(region.target) + 1 :]
        m = _TABLE_REGION.match(short)
        if m:
            landmark = next(
                (
                    e
                    for e in model.names
                    if model.category_of(e).endswith(m.group("landmark")) or m.group("landmark") in model.category_of(e)
                ),
                None,
            )
            if landmark:
                model.dest_phrases[region.name] = ("", f"{_SIDES[m.group('side')]} {model.names[landmark]}")


def _anchor(language: str, model: TaskModel, step: Step) -> int:
    if step.kind in ("open", "close", "turn_on", "turn_off"):
        word = {"open": "open", "close": "close", "turn_on": "turn on", "turn_off": "turn off"}[step.kind]
        i = language.find(word)
        return i if i >= 0 else 10_000
    noun = model.names.get(step.objects[0], "")
    words = [w for w in noun.split() if w != "the"]
    i = language.find(" ".join(words)) if words else -1
    return i if i >= 0 else 5_000


def _steps(model: TaskModel) -> None:
    problem, language = model.problem, model.task.language
    places: dict[tuple[str, str], list[str]] = {}
    steps: list[Step] = []
    for atom in problem.goal:
        head = atom[0]
        if head in STATE_KINDS:
            if model.always(*atom):  # already true in every initial state: nothing to do
                continue
            steps.append(Step(STATE_KINDS[head], (atom[1],), goal=(atom,)))
        elif head in ("on", "in"):
            places.setdefault((atom[2], head), []).append(atom[1])
    for (dest, head), objs in places.items():
        prep = model.dest_phrases.get(dest, (head, ""))[0]
        if head == "on" and re.search(rf"\bin {re.escape(model.names.get(dest, '@'))}", language):
            prep = "in"  # "put the cream cheese in the bowl" (BDDL says on)
        kind = "push" if language.startswith("push") else "place"
        steps.append(Step(kind, tuple(objs), dest, prep, tuple((head, o, dest) for o in objs)))
        region = model.facts.entities.get(dest)
        if (
            region is not None
            and region.kind == "region"
            and model.facts.predicate("open", dest) != model.facts.states()
            and not {("open", dest), ("close", dest)} & set(problem.goal)
            and _is_drawer(dest, model)
        ):
            steps.append(Step("open", (dest,), goal=(("open", dest),)))
    model.steps = sorted(steps, key=lambda s: _anchor(language, model, s))


def _is_drawer(region: str, model: TaskModel) -> bool:
    parent_cat = model.category_of(model.parent(region))
    return "drawer" in region_names(region, parent_cat)


def build_model(task: BaseTask, facts: TaskFacts) -> TaskModel:
    model = TaskModel(task, facts)
    _name_entities(model)
    _dest_phrases(model)
    _steps(model)
    return model
