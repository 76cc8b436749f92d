"""The physical family's rules, per case and per suite.

Per case (:func:`check_affordance`; the shared :mod:`.structure` rules already check that every
subgoal is still asked, naming its original object and destination, and that added steps come first):

- every violation names a ``kind`` (rigidity, fixed, size, containment, articulation, switch,
  pouring) and the affordance that kind is about; ``support`` ("the plate standing on top of the
  wine bottle") is rejected: a plate can balance on a bottle mouth, so it is never plainly
  impossible;
- observable: an episode ends as soon as the original goal holds, so a violation of an original,
  goal-reaching step is about what that step acts on (its object, or a drawer's fixture), never an
  added participant joined to it; the joining forms ("together with", "along with", "as well as",
  "while ...", "with X tucked/packed inside Y", "both X and Y" where the base task has no "both")
  are rejected wherever they appear;
- ``pouring`` is rejected as disputable ("pour the butter into the basket" reads as tipping the
  package in), and a ``containment`` holder must plainly never open and have no "box", "carton",
  "bag" or "package" in its name (a box invites being opened);
- a step right after a step with a violation never opens with "put it"/"place it": that step may
  have handled two things;
- a ``fixed`` violation moves the fixture: its text never uses a verb of only holding or touching
  it ("while holding the stove"): gripping a fixture in place is possible;
- no object is grasped twice in a row: a step never grasps (picks up, lifts, takes, grabs) the same
  object twice, and two consecutive steps never both grasp the same object ("lift the butter, then
  pick up the butter, switch on the butter and put it in the basket" repeats the pick-up);
- no step repeats a connective ("together with the cabinet together with the stove"): two added
  participants of one step are coordinated;
- its entity is in the scene, and its ``text`` is in the instruction and names the entity;
- the affordance table PLAINLY denies it (``false``; ``fixed`` ``true`` for "movable"); a size
  violation names a holder that is a real container a whole size class too small, never a box,
  carton, bag or package;
- the level's shape: L1 one violation; L2 at least two in the one step, each about a different
  (entity, affordance); L3 exactly one; L4 violations in at least two different steps; no
  violation repeated.

Per suite (:func:`suite_problems`, for the lead's suite-level check): each level cell (all physical
cases of one level) has at least ``MIN_KINDS`` kinds (L2: ``MIN_KINDS_BY_LEVEL``); no sentence
skeleton (:func:`skeleton`) is more than ``MAX_SKELETON_SHARE`` of its cell; no text appears twice
within one LIBERO suite.
"""

from __future__ import annotations

import re
from collections import Counter, defaultdict
from collections.abc import Iterable, Mapping

from conflictbench.core import ConflictCase
from conflictbench.tasks.operators.instruction import denotes_only
from conflictbench.tasks.scene.affordances import AFFORDANCES, category, load_table
from conflictbench.tasks.scene.task_model import TaskModel

from .text import entity_names, names_in, normalise

NEEDS = (*AFFORDANCES, "movable", "fits_in")
KIND_NEEDS = {
    "rigidity": ("foldable",),
    "fixed": ("graspable", "movable"),
    "size": ("fits_in",),
    "containment": ("container",),
    "articulation": ("openable",),
    "switch": ("turnable",),
    "pouring": ("pourable",),
}
DISPUTABLE_KINDS = {
    "support": "a plate can balance on a bottle, a box on a carton laid down",
    "pouring": "pouring a packaged food reads as tipping the package in",
}
JOINED = re.compile(r"\b(?:together with|along with|as well as|while|tucked|packed)\b|\bwith\b.*\binside\b")
"""Forms that join an added participant to a step: the robot can reach the goal before it."""
NOT_HOLDERS = ("box", "carton", "bag", "package")
PRONOUN_OPENER = re.compile(r"^(?:put|place|set|slide|drop|move) (?:it|them)\b")
HOLDING_ONLY = re.compile(r"\b(?:hold|grip|grasp|touch|clutch|squeeze)(?:s|es|ing|ed)?\b|\bheld\b")
"""Verbs that keep a fixture where it is: no violation of "fixed"."""
GRASP = re.compile(r"\b(?:pick up|lift|take|grab)\s+(?:the\s+)?")
"""Verbs that grasp their object: one grasp per object in a row."""
CONNECTIVES = ("together with", "along with", "as well as", "while")
MIN_KINDS = 4
MIN_KINDS_BY_LEVEL = {"L2": 3}
"""L2's two violations share one step, and since suite 2.1 a too-small holder is a step of its own
(putting the object into it is a placement), so one step offers its object's manners (rigidity,
switch, articulation) and a fixture lifted before it is operated, which no L2 task pairs."""
MAX_SKELETON_SHARE = 0.25
PLACEHOLDER = "<e>"


def _denied(model: TaskModel, v: dict, present: set[str]) -> list[str]:
    entity, needs = v["entity"], v["needs"]
    info = category(model.category_of(entity))
    if needs == "fits_in":
        holder = v.get("holder")
        if holder not in present:
            return [f"violation: holder {holder!r} is not in the scene"]
        outer = category(model.category_of(holder))
        if not (outer.has("container") is True and info.size > outer.size):
            return [f"{entity} may fit inside {holder}: the holder is no container a size class smaller"]
        if not names_in(v["text"], entity_names(model, holder)):
            return [f"violation text {v['text']!r} does not name {holder}"]
        if holder in model.names and any(w in model.name(holder) for w in NOT_HOLDERS):
            return [f"size holder {holder}: a box, carton, bag or package invites opening or stretching"]
        return []
    denied = info.has("fixed") is True if needs == "movable" else info.lacks(needs)
    if not denied:
        return [f"{entity} ({info.category}) does not plainly lack {needs!r} in the affordance table"]
    return []


def check_affordance(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out: list[str] = []
    present = set(model.problem.objects) | set(model.problem.fixtures)
    violations = case.witness.get("violations", [])
    for v in violations:
        entity, needs, kind, text = v.get("entity"), v.get("needs"), v.get("kind"), str(v.get("text", ""))
        if kind in DISPUTABLE_KINDS:
            out.append(f"violation: kind {kind!r} is disputable ({DISPUTABLE_KINDS[kind]})")
        elif kind not in KIND_NEEDS:
            out.append(f"violation: unknown kind {kind!r} (one of {', '.join(KIND_NEEDS)})")
        elif needs not in KIND_NEEDS[kind]:
            out.append(f"violation: kind {kind!r} is about {' or '.join(KIND_NEEDS[kind])}, not {needs!r}")
        if entity not in present:
            out.append(f"violation: {entity!r} is not in the scene")
            continue
        if needs not in NEEDS:
            out.append(f"violation: unknown affordance {needs!r}")
            continue
        if not text or text not in case.instruction:
            out.append(f"violation text {text!r} is not in the instruction")
        if needs == "fits_in":
            if not names_in(case.instruction, entity_names(model, entity)):
                out.append(f"the instruction does not name {entity}")
        elif not names_in(text, entity_names(model, entity)):
            out.append(f"violation text {text!r} does not name {entity}")
        if entity in model.goal_twins() and not any(
            names_in(text, [n]) and denotes_only(model, n, entity) for n in entity_names(model, entity)
        ):
            out.append(f"violation text {text!r} names {entity} by a noun its identical twin shares: name it in full")
        if kind == "fixed" and HOLDING_ONLY.search(text):
            out.append(f"fixed violation {text!r} only holds or touches the fixture: it must move it")
        out += _denied(model, v, present)
        out += _placement_inside_a_step(case, v)
    out += _observable(case, model, violations) + _regrasps(case, model)
    return out + _repeated_connectives(case) + _level_shape(case, violations)


def _placement_inside_a_step(case: ConflictCase, v: dict) -> list[str]:
    """Putting the object into a too-small holder is a placement with its own goal: a step of its
    own, never the manner of an original step ("squeeze the book into the mug and put the book in
    the caddy" is two placements; suite 2.0's readers counted it as two steps)."""
    roles, step = case.witness.get("step_roles") or [], v.get("step")
    if v.get("kind") != "size" or not isinstance(step, int) or not 1 <= step <= len(roles):
        return []
    if roles[step - 1] == "original":
        return [f"size violation {v.get('text')!r} puts the object somewhere first: a step of its own, not a manner"]
    return []


def _observable(case: ConflictCase, model: TaskModel, violations: list) -> list[str]:
    """Violations reached before the original goal ends the episode; no joined participants; no
    "put it" right after a step with a violation; containment only in plainly sealed holders."""
    out: list[str] = []
    text = normalise(case.instruction)
    if JOINED.search(text):
        out.append(f"joined participant {JOINED.search(text).group(0)!r}: the goal can be met before it is reached")
    if re.search(r"\bboth\b", text) and not re.search(r"\bboth\b", normalise(model.task.language)):
        out.append("'both X and Y' adds a participant: the goal can be met before it is reached")
    bodies = [normalise(str(b)) for b in case.witness.get("steps") or []]
    for v in violations:
        i = int(v.get("step", 0)) - 1
        out += _reached(case.witness, i, v)
        if 0 <= i + 1 < len(bodies) and PRONOUN_OPENER.match(bodies[i + 1]):
            out.append(f"step {i + 2} opens with a pronoun after a step with a violation: name the object")
        out += _sealed_holder(model, v)
    return out


def _reached(witness: dict, i: int, v: dict) -> list[str]:
    """A violation in an original step that reaches its goal is about what the step acts on: an added
    participant may never be reached before the goal ends the episode."""
    roles = witness.get("step_roles") or []
    goals = witness.get("step_goals") or []
    acted = witness.get("step_entities") or []
    if 0 <= i < len(roles) and roles[i] == "original" and i < len(goals) and goals[i]:
        if i < len(acted) and v.get("entity") not in acted[i]:
            return [f"step {i + 1} reaches its goal: {v.get('entity')} is an added participant, maybe never reached"]
    return []


def _sealed_holder(model: TaskModel, v: dict) -> list[str]:
    """Containment only in a holder that plainly cannot open (not a box, carton, bag or package)."""
    if v.get("kind") == "containment" and v.get("entity") in model.names:
        info = category(model.category_of(v["entity"]))
        names = " ".join((*info.names, model.name(v["entity"])))
        if not info.lacks("openable") or any(w in names for w in NOT_HOLDERS):
            return [f"containment in {v['entity']}: a box, carton, bag or package, or what may open, invites opening"]
    return []


def _grasped(body: str, model: TaskModel) -> list[set[str]]:
    """For each grasping verb in a step, the entities its object phrase may denote: those with the
    longest name that opens the phrase ("the black bowl" alone denotes both twin bowls)."""
    names = [(normalise(n), e) for e in model.facts.entities for n in model.entity_names(e)]
    out = []
    for match in GRASP.finditer(body):
        rest = f"{body[match.end() :]} "
        hits = [(len(n), e) for n, e in names if n and rest.startswith(f"{n} ")]
        if hits:
            longest = max(length for length, _ in hits)
            out.append({e for length, e in hits if length == longest})
    return out


def _regrasps(case: ConflictCase, model: TaskModel) -> list[str]:
    """A step grasping an object twice, or right after the step before grasped it: a repeated pick-up."""
    out: list[str] = []
    before: set[str] = set()
    for i, body in enumerate((normalise(str(b)) for b in case.witness.get("steps") or []), start=1):
        grasps = _grasped(body, model)
        here: set[str] = set()
        for objects in grasps:
            if objects & here:
                out.append(f"step {i} grasps {sorted(objects & here)[0]} twice: one pick-up per object")
            elif objects & before:
                out.append(f"step {i} grasps {sorted(objects & before)[0]} again right after step {i - 1}")
            here |= objects
        before = here
    return out


def _step_spans(case: ConflictCase) -> list[str]:
    """Each step's text with its clauses: from its body to the next step's body (the witness's
    ``steps`` hold the bodies only)."""
    starts, pos = [], 0
    for body in case.witness.get("steps") or []:
        i = case.instruction.find(str(body), pos)
        if i < 0:
            return [case.instruction]
        starts.append(i)
        pos = i + len(str(body))
    ends = [*starts[1:], len(case.instruction)]
    return [case.instruction[a:b] for a, b in zip(starts, ends, strict=True)] or [case.instruction]


def _repeated_connectives(case: ConflictCase) -> list[str]:
    out = []
    for i, span in enumerate(_step_spans(case), start=1):
        text = f" {normalise(span)} "
        for phrase in CONNECTIVES:
            if text.count(f" {phrase} ") > 1:
                out.append(f"step {i} repeats {phrase!r}: coordinate the added participants instead")
    return out


def _level_shape(case: ConflictCase, violations: list) -> list[str]:
    keys = [(v.get("step"), v.get("entity"), v.get("needs")) for v in violations if isinstance(v, dict)]
    out = []
    if len(set(keys)) != len(keys):
        out.append("a violation is repeated: each factor must be impossible on its own")
    steps = {k[0] for k in keys}
    if case.level == "L2":
        if len(steps) != 1:
            out.append("L2: both violations must be in the one step")
        if len({(k[1], k[2]) for k in keys}) < 2:
            out.append("L2: needs two different violations (entity or affordance) in its step")
    if case.level in ("L1", "L3") and len(keys) != 1:
        out.append(f"{case.level}: exactly one violation, found {len(keys)}")
    if case.level == "L4" and len(steps) < 2:
        out.append("L4: violations must be in at least two different steps")
    return out


# -- suite level ----------------------------------------------------------------------------------
def _phrases(model: TaskModel) -> list[str]:
    """Every phrase that names an entity of the task: names, destination phrases, category words."""
    out: set[str] = set()
    for e in model.facts.entities:
        out |= {normalise(n) for n in model.entity_names(e)}
    for name in model.names.values():
        out.add(normalise(name.removeprefix("the ")))
    for _, phrase in model.dest_phrases.values():
        out.add(normalise(phrase.removeprefix("the ")))
    for info in load_table().values():
        out |= {normalise(n) for n in info.names}
    return sorted((p for p in out if p), key=len, reverse=True)


def skeleton(case: ConflictCase, model: TaskModel) -> str:
    """The instruction with every entity phrase replaced by a placeholder (longest phrases first)."""
    text = f" {normalise(case.instruction)} "
    for phrase in _phrases(model):
        text = re.sub(rf"(?<= ){re.escape(phrase)}(?= )", PLACEHOLDER, text)
    text = re.sub(rf"\b(?:the|both) (?={re.escape(PLACEHOLDER)})", "", text)
    return " ".join(text.split())


def kinds_of(case: ConflictCase) -> list[str]:
    return [str(v.get("kind")) for v in case.witness.get("violations", []) if isinstance(v, dict)]


def suite_problems(cases: Iterable[ConflictCase], models: Mapping[tuple[str, int], TaskModel]) -> list[tuple[str, str]]:
    """(case_id, reason) for the family's suite-wide rules: kinds and skeletons per level cell,
    no text twice within one LIBERO suite."""
    physical = [c for c in cases if c.family == "physical" and c.status != "removed"]
    out: list[tuple[str, str]] = []
    cells: dict[str, list[ConflictCase]] = defaultdict(list)
    for c in physical:
        cells[c.level].append(c)
    for level, cell in sorted(cells.items()):
        kinds = {k for c in cell for k in kinds_of(c)}
        need = MIN_KINDS_BY_LEVEL.get(level, MIN_KINDS)
        if len(kinds) < need:
            out.append((cell[0].case_id, f"physical {level}: {len(kinds)} kind(s) {sorted(kinds)}, need {need}"))
        shapes = {c.case_id: skeleton(c, models[c.suite, c.task_id]) for c in cell}
        for shape, n in Counter(shapes.values()).items():
            if n > MAX_SKELETON_SHARE * len(cell):
                first = next(cid for cid, s in shapes.items() if s == shape)
                out.append((first, f"physical {level}: skeleton {shape!r} is {n} of {len(cell)} cases"))
    seen: dict[tuple[str, str], str] = {}
    for c in physical:
        key = (c.suite, normalise(c.instruction))
        if key in seen:
            out.append((c.case_id, f"same text as {seen[key]} within {c.suite}"))
        seen.setdefault(key, c.case_id)
    return out
