"""The spatial family's rules: a presupposed relation that is false, visibly, and still false when
its step is reached.

A case's witness lists ``relations``: per relation its ``step`` (1-based), the ``text`` the step
says it with, the ``relation`` (left_of, right_of, in_front_of, behind, next_to, between, on, in),
the ``subject`` and ``landmarks`` (each a phrase and every scene entity the phrase could denote)
and, for a direction, ``margin_m``. A relation is valid when:

- **False everywhere it pairs**: it holds, under the lenient reading of
  :meth:`.scene.facts.TaskFacts.holds`, for no combination of the entities its words could denote,
  in no initial state the case is paired with (all 50, or at least ``MIN_STATES`` listed ones).
- **Visibly false**: a direction (left/right of, in front of, behind) is false by at least
  ``max(6 cm, the subject's radius)`` past the landmark's centre AND with the two footprints a
  centimetre apart along its axis (``FOOTPRINT_GAP``), in every paired state, as recomputed from the
  scene facts; the witness's ``margin_m`` is that smallest footprint gap. "Between" is false only
  past an end by the footprints too; "next to" is measured between footprints already.
- **In LIBERO's frame, and said whether the robot's agrees**: directions are the agentview camera's
  (LIBERO's own task language: left = the image's left, -y; front = toward the camera, +x). Each
  relation records ``frame_independent``: whether it is also false read from the robot's side
  (left and right, front and behind swapped); the witness's flag is whether all are.
- **Still false when reached**: no entity of the relation (subject or landmark, or their parent
  fixture) is moved or operated by an EARLIER step (the witness's ``step_entities`` and what the
  steps' goals imply), nor rests on or in a thing such a step moves (:func:`riders`: a bowl on the
  cookie box moves with the box), and no landmark is moved or operated by the relation's own step.
- **Nothing a reader cannot judge**: no relation about an entity with an identical twin (the two
  black bowls of libero_spatial: "the black bowl next to the ramekin that is behind the stove"
  attaches to the ramekin as readily as to the bowl), none about a drawer's hidden contents, no
  direction against a fixture that faces its own way (a cabinet's drawers), no "next to" between
  two things of one kind.
- **Never a destination**: the relation follows its subject as a relative clause or a participle
  ("the butter that is to the left of the milk", "the bowl sitting on the plate"); after a motion
  verb a bare one ("take the butter to the left of the milk") reads as where to put it.
- **Landmarks resolve**: each landmark phrase denotes one thing (an object, or a fixture with its
  regions); a twin's bare noun ("the black bowl" beside its identical twin) is never a landmark.
- **Readable**: said inside its own step; no "left"/"right" (or "front"/"back") in a phrase of a
  relation on the same axis ("the left plate to the right of ..."); "on" only for a movable subject
  and a support at least as large, "in" only for a container at least as large; no claim twice.
- **Level**: L2's relations all sit in its one step, about two parts or two claims about one part.
"""

from __future__ import annotations

from conflictbench.core import ConflictCase
from conflictbench.tasks.scene.affordances import category
from conflictbench.tasks.scene.facts import DIRECTIONS, FOOTPRINT_GAP, RELATIONS
from conflictbench.tasks.scene.task_model import TaskModel

from .text import names_in

CLAUSE_OPENERS = (" that is ", " which is ", " sitting ", " resting ", " standing ")
"""How a relation's text goes on after its subject: a clause or participle, never a bare modifier."""
MIN_STATES = 25
"""A claim false in fewer of the 50 initial states is not used (the case would pair too rarely)."""
RELATION_WORDS = {
    "left_of": ("left",),
    "right_of": ("right",),
    "in_front_of": ("in front of",),
    "behind": ("behind",),
    "next_to": ("next to", "beside"),
    "on": ("on", "on top of"),
    "in": ("in", "inside"),
    "between": ("between",),
}
SAME_AXIS_WORDS = {
    "left_of": ("left", "right"),
    "right_of": ("left", "right"),
    "in_front_of": ("front", "back", "rear", "behind"),
    "behind": ("front", "back", "rear", "behind"),
}
"""Words that, inside a subject or landmark phrase, make a direction read as a contradiction."""
RIDER_RISE = 0.005
"""A thing touching another counts as resting on it when its origin is this much higher (metres): a
bowl on the cookie box sits 8 mm above the box's origin, a plate merely grazing a bowl 3 mm."""
ROBOT_FRAME = {"left_of": "right_of", "right_of": "left_of", "in_front_of": "behind", "behind": "in_front_of"}
"""A direction read from the robot's side of the table, as LIBERO's (the camera's) frame says it: the
robot faces the camera, so its left is the image's right and its front (nearer the robot) the
camera's behind."""
MARGIN_SLACK = 0.0015
"""Positions are stored in millimetres: a witness margin may differ from the recomputed one by this."""


def check_relation(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out: list[str] = []
    if case.init_states is not None and len(states) < MIN_STATES:
        out.append(f"paired with {len(states)} initial state(s); a claim needs at least {MIN_STATES}")
    relations = case.witness.get("relations", [])
    steps = case.witness.get("steps", [])
    acted = acted_per_step(case, model)
    for r in relations:
        out += _one_relation(case, model, states, r, steps, acted)
    out += _claims_and_level(case, relations)
    every = all(isinstance(r, dict) and r.get("frame_independent") is True for r in relations)
    if case.witness.get("frame_independent") is not every:
        out.append(f"witness frame_independent must be {every}: whether every relation is false in both frames")
    return out


def frame_independent(model: TaskModel, rel: str, combos: list[list[str]], states: frozenset) -> bool:
    """Is the claim also false read from the robot's side (:data:`ROBOT_FRAME`), in every paired
    state and for every combination of what its words could denote? Relations without a direction
    read the same from anywhere."""
    if rel not in ROBOT_FRAME:
        return True
    return not any(model.facts.holds(ROBOT_FRAME[rel], *combo) & states for combo in combos)


def _one_relation(case, model: TaskModel, states, r: dict, steps: list, acted: list[set[str]]) -> list[str]:
    rel, text, step = r.get("relation"), str(r.get("text", "")), r.get("step")
    if rel not in RELATIONS:
        return [f"unknown relation {rel!r}"]
    out = []
    if text not in case.instruction:
        out.append(f"relation text {text!r} is not in the instruction")
    if isinstance(step, int) and 1 <= step <= len(steps) and text not in steps[step - 1]:
        out.append(f"relation text {text!r} is not in step {step} ({steps[step - 1]!r})")
    args = [r.get("subject", {})] + list(r.get("landmarks", []))
    if len(args) != (3 if rel == "between" else 2):
        return out + [f"{rel} takes {3 if rel == 'between' else 2} arguments, got {len(args)}"]
    found, groups = _argument_groups(model, rel, text, args)
    out += found
    if groups is None:
        return out
    out += _wording(rel, text, args)
    out += _unseen_or_unattached(model, r, rel)
    out += _as_clause(r, text)
    out += _landmarks_single(model, r)
    out += _holder(model, rel, groups)
    out += _when_reached(r, groups, acted, model)
    return out + _false_everywhere(model, r, rel, groups, states)


def _argument_groups(model: TaskModel, rel: str, text: str, args: list[dict]) -> tuple[list[str], list | None]:
    """Each argument's entities (sorted), all in the scene and all that its phrase could mean, the phrase named by
    the relation's text; with the problems found (groups None: an argument lists nothing, or what is not there)."""
    out, groups = [], []
    for arg in args:
        listed = set(arg.get("entities", []))
        unknown = listed - set(model.facts.entities)
        if not listed or unknown:
            return out + [f"relation {rel}: entities {sorted(unknown) or '(none)'} are not in the scene"], None
        missing = model.candidates(str(arg.get("phrase", ""))) - listed
        if missing:
            out.append(f"relation {rel}: {arg.get('phrase')!r} could also mean {', '.join(sorted(missing))}")
        if not names_in(text, {str(arg.get("phrase", ""))}):
            out.append(f"relation text {text!r} does not name {arg.get('phrase')!r}")
        groups.append(sorted(listed))
    return out, groups


def _wording(rel: str, text: str, args: list[dict]) -> list[str]:
    """The text says the relation, and no phrase carries a word of the same axis ("the left bowl to the right")."""
    out = []
    if not any(names_in(text, {w}) for w in RELATION_WORDS[rel]):
        out.append(f"relation text {text!r} does not say {rel.replace('_', ' ')}")
    phrases = [str(a.get("phrase", "")) for a in args]
    clash = [w for p in phrases for w in SAME_AXIS_WORDS.get(rel, ()) if names_in(p, {w})]
    if clash:
        out.append(f"{rel.replace('_', ' ')} about {' / '.join(phrases)!r}: {clash[0]!r} reads as a contradiction")
    return out


def _false_everywhere(model: TaskModel, r: dict, rel: str, groups: list, states: frozenset) -> list[str]:
    """For every combination of what the words could mean, the relation is false in every paired state (a
    direction by a camera-visible margin), and the witness's frame_independent is what the robot's side says."""
    out = []
    combos = referent_combos(groups)
    if rel in DIRECTIONS:
        out += _margin(r, rel, combos, model, states)
    independent = frame_independent(model, rel, combos, states)
    if r.get("frame_independent") is not independent:
        out.append(
            f"witness frame_independent {r.get('frame_independent')!r} for {rel}: the claim is "
            f"{'also' if independent else 'not'} false read from the robot's side ({independent})"
        )
    for combo in combos:
        true_in = model.facts.holds(rel, *combo) & states
        if true_in:
            out.append(f"{rel}{tuple(combo)} holds in initial state(s) {sorted(true_in)[:5]}")
    return out


def _margin(r: dict, rel: str, combos: list[list[str]], model: TaskModel, states: frozenset) -> list[str]:
    """A direction must be false by what a camera shows, measured between FOOTPRINTS along the
    relation's axis in every paired state: recomputed here, and the witness's margin_m must agree."""
    facts, out = model.facts, []
    idx = sorted(states)
    smallest = None
    for a, b in combos:
        clear = float(facts.clearance(rel, a, b)[idx].min())
        need = facts.direction_margin(a)
        if clear < need:
            out.append(f"{rel}({a}, {b}) is false by only {clear:.3f} m between centres; a camera needs {need:.3f} m")
        apart = float(facts.footprint_gap(rel, a, b)[idx].min())
        if apart < FOOTPRINT_GAP:
            out.append(
                f"{rel}({a}, {b}): their footprints are {apart:.3f} m apart along the axis (overlapping where "
                f"negative); a false direction needs {FOOTPRINT_GAP:.3f} m"
            )
        smallest = apart if smallest is None else min(smallest, apart)
    said = r.get("margin_m")
    if not isinstance(said, int | float):
        out.append(f"a {rel.replace('_', ' ')} relation needs its margin_m in the witness")
    elif smallest is not None and abs(said - smallest) > MARGIN_SLACK:
        out.append(f"witness margin_m {said} does not match the scene facts' footprint gap ({smallest:.3f} m)")
    return out


def has_own_front(model: TaskModel, entity: str) -> bool:
    """A fixture with drawers or a door faces its own way: "in front of the cabinet" may mean its
    drawers' side rather than the camera's, so no direction is claimed against it."""
    holder = model.parent(entity)
    info = model.facts.entities.get(holder)
    return info is not None and info.kind == "fixture" and category(model.category_of(holder)).has("openable") is True


def same_kind_pair(model: TaskModel, subject: str, landmarks) -> bool:
    """Two things of one kind (the left and the right plate) read as "beside each other" at any gap."""
    return any(model.category_of(subject) == model.category_of(e) for e in landmarks)


def _unseen_or_unattached(model: TaskModel, r: dict, rel: str) -> list[str]:
    """Two forms readers could not judge: a claim about what is inside a drawer (a closed drawer
    hides its contents from the camera) and a claim about a twinned object ("the black bowl between
    the plate and the ramekin that is left of the stove": the clause attaches to the ramekin as
    readily as to the bowl)."""
    out = []
    marks = [e for lm in r.get("landmarks", []) for e in lm.get("entities", [])]
    if rel == "next_to" and any(same_kind_pair(model, s, marks) for s in r.get("subject", {}).get("entities", [])):
        out.append("a 'next to' relation between two things of one kind: a pair reads as side by side")
    if rel in DIRECTIONS and any(has_own_front(model, e) for e in marks):
        out.append(f"a {rel.replace('_', ' ')} relation to a fixture that faces its own way (drawers or a door)")
    if rel == "in" and any("drawer" in str(lm.get("phrase", "")) for lm in r.get("landmarks", [])):
        out.append("an 'in' relation about a drawer's contents: the camera cannot see inside a closed drawer")
    subject = set(r.get("subject", {}).get("entities", []))
    subject |= {model.parent(e) for e in subject}
    if subject & (model.goal_twins() | model.unnamed):  # the scored bowl, or its unnamed twin
        out.append("a relation about a twinned object: its clause could attach to the twin's identifying landmark")
    return out


def _as_clause(r: dict, text: str) -> list[str]:
    """The relation follows its subject as a relative clause or a participle: after a motion verb a
    bare one ("take the butter to the left of the milk") reads as where to put the thing."""
    subject = "the " + str(r.get("subject", {}).get("phrase", ""))
    rest = text[len(subject) :] if text.startswith(subject) else None
    if rest is None or not rest.startswith(CLAUSE_OPENERS):
        return [f"relation text {text!r} is not a relative clause or participle after {subject!r}"]
    return []


def _landmarks_single(model: TaskModel, r: dict) -> list[str]:
    """Each landmark phrase denotes one thing (an object, or a fixture with its regions): "the black
    bowl" where two identical bowls stand leaves the relation unresolved."""
    out = []
    for lm in r.get("landmarks", []):
        things = {model.parent(e) for e in lm.get("entities", [])}
        if len(things) > 1:
            out.append(f"landmark {lm.get('phrase')!r} could mean any of {', '.join(sorted(things))}")
    return out


def riders(model: TaskModel, entity: str) -> set[str]:
    """Objects that rest on or in ``entity`` (or one of its regions) in some initial state: LIBERO's
    on/in predicates, or a contact with the object's origin ``RIDER_RISE`` higher than ``entity``'s.
    Moving ``entity`` moves them."""
    facts = model.facts
    bases = {entity} | {e for e, info in facts.entities.items() if info.kind == "region" and info.parent == entity}
    out = set()
    for o, info in facts.entities.items():
        if info.kind != "object" or o == entity:
            continue
        if any(facts.predicate(rel, o, b) for rel in ("on", "in") for b in bases):
            out.add(o)
            continue
        touch = sorted(facts.touching(o, entity))
        if touch and (facts.positions[o][touch, 2] - facts.positions[entity][touch, 2] >= RIDER_RISE).any():
            out.add(o)
    return out


def _holder(model: TaskModel, rel: str, groups: list[list[str]]) -> list[str]:
    """ "on" needs a movable subject and a support, "in" a container, at least as large as the subject."""
    if rel not in ("on", "in"):
        return []
    out = []
    need = "support" if rel == "on" else "container"
    for subject in groups[0]:
        if model.facts.entities[subject].kind != "object":
            out.append(f"{rel}: {subject} is not a movable object")
            continue
        size = category(model.category_of(subject)).size
        for landmark in groups[1]:
            holder = model.parent(landmark)
            info = category(model.category_of(holder))
            if info.has(need) is not True or info.size < size:
                out.append(f"{rel}: {holder} is an absurd holder for {subject} (not a {need} its size)")
    return out


def _when_reached(r: dict, groups: list[list[str]], acted: list[set[str]], model: TaskModel) -> list[str]:
    step = r.get("step")
    if not isinstance(step, int) or not 1 <= step <= len(acted):
        return []
    earlier = set().union(*acted[: step - 1]) if step > 1 else set()
    out = []
    for i, group in enumerate(groups):
        for entity in group:
            touched = {entity, model.parent(entity)} & earlier
            if touched:
                out.append(
                    f"step {step}'s relation is about {entity}, which an earlier step moves or operates "
                    f"({', '.join(sorted(touched))}): it may no longer be false when the step is reached"
                )
            if i > 0 and {entity, model.parent(entity)} & acted[step - 1]:
                out.append(f"step {step}'s relation uses {entity}, which that same step moves, as its landmark")
    return out


def acted_per_step(case: ConflictCase, model: TaskModel) -> list[set[str]]:
    """Per step, the entities it moves or operates: what the witness's ``step_entities`` says, what
    the step's goals imply (the moved objects; the operated region and its fixture), for an added
    step everything it names outside its relation phrases (a step the goals do not describe is read
    conservatively), and whatever rests on or in any of those."""
    w = case.witness
    steps = w.get("steps", [])
    said = w.get("step_entities") or [[] for _ in steps]
    goals = w.get("step_goals") or [[] for _ in steps]
    roles = w.get("step_roles") or ["original" for _ in steps]
    texts = {int(r.get("step", 0)): [] for r in w.get("relations", [])}
    for r in w.get("relations", []):
        texts[int(r.get("step", 0))].append(str(r.get("text", "")))

    def moved(literals) -> set[str]:
        out = set()
        for lit in literals:
            if lit and lit[0] in ("on", "in"):
                out.add(str(lit[1]))
            elif len(lit) > 1:
                out |= {str(lit[1]), model.parent(str(lit[1]))}
        return out

    acted = []
    for i in range(len(steps)):
        here = set(map(str, said[i] if i < len(said) else [])) | moved(goals[i] if i < len(goals) else [])
        role = roles[i] if i < len(roles) else "original"
        if role == "added":
            rest = steps[i]
            for t in texts.get(i + 1, []):
                rest = rest.replace(t, " ")
            here |= {e for e in model.facts.entities if names_in(rest, _own_names(model, e))}
        here |= {model.parent(e) for e in here}
        acted.append(here | {o for e in here for o in riders(model, e)})
    return acted


def _own_names(model: TaskModel, entity: str) -> set[str]:
    """Names that pick out this entity (or its own regions) alone: "ketchup", "top drawer", not
    "table" for every table region."""
    mine = {entity, model.parent(entity)} | {e for e in model.facts.entities if model.parent(e) == entity}
    return {n for n in model.entity_names(entity) if model.candidates(n) <= mine}


def _claims_and_level(case: ConflictCase, relations: list) -> list[str]:
    out, seen = [], set()
    for r in relations:
        if not isinstance(r, dict):
            continue
        claim = (
            r.get("relation"),
            tuple(sorted(r.get("subject", {}).get("entities", []))),
            tuple(tuple(sorted(lm.get("entities", []))) for lm in r.get("landmarks", [])),
        )
        if claim in seen:
            out.append(f"the claim {r.get('relation')} about {r.get('subject', {}).get('phrase')!r} is made twice")
        seen.add(claim)
    if case.level == "L2" and len(relations) >= 2:
        if {r.get("step") for r in relations if isinstance(r, dict)} != {1}:
            out.append("an L2 case's relations must all sit in its one step")
    return out


def referent_combos(groups: list[list[str]]) -> list[list[str]]:
    combos: list[list[str]] = [[]]
    for g in groups:
        combos = [c + [x] for c in combos for x in g if x not in c]
    return combos
