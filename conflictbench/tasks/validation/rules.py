"""Automatic validation of conflict cases: every rule the issue names, re-checked from data.

Rules for every case: the base task exists and its reference instruction is the case's
``base_instruction``; the base task is unchanged (its BDDL file and initial states hash to what
the scene facts were derived from) and still valid (goal entities exist, the goal is not already
met in an initial state); the instruction differs from the base instruction and from every other
case of the base task; the witness has the family's type; its ``steps`` occur in the instruction,
in order; the level matches the witness (L1 one step one factor, L2 one step several factors,
L3 several steps one factor, L4 several steps with factors in at least two of them). Then the
family's own rule (:data:`FAMILY_CHECKS`). Scene facts come from package data, so no simulator runs.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from conflictbench.core import ConflictCase
from conflictbench.tasks.libero.base_tasks import base_task
from conflictbench.tasks.operators.contradictions import contradiction, literal_entities
from conflictbench.tasks.scene.affordances import AFFORDANCES, category, fits_inside
from conflictbench.tasks.scene.facts import RELATIONS, TaskFacts, file_sha256, load_scene_facts, states_sha256
from conflictbench.tasks.scene.lexicon import absence_problem, words
from conflictbench.tasks.scene.lexicon import concept as absent_concept
from conflictbench.tasks.scene.task_model import TaskModel, build_model

WITNESS_TYPES = {
    "instruction": "contradiction",
    "grounding": "absent_referent",
    "spatial": "false_relation",
    "physical": "affordance_violation",
}
FACTOR_KEYS = {
    "contradiction": "conflicts",
    "absent_referent": "referents",
    "false_relation": "relations",
    "affordance_violation": "violations",
}
NEEDS = (*AFFORDANCES, "movable", "fits_in")
PRONOUNS = {"it", "them", "its", "both"}
RELATION_WORDS = {
    "left_of": ("left",),
    "right_of": ("right",),
    "in_front_of": ("in front of",),
    "behind": ("behind",),
    "next_to": ("next to", "beside"),
    "on": ("on",),
    "in": ("in", "inside"),
    "between": ("between",),
}


def normalise(text: str) -> str:
    return " ".join(words(text))


@dataclass
class Context:
    """Everything validation reads, loaded once per run."""

    facts: dict[tuple[str, int], TaskFacts]
    models: dict[tuple[str, int], TaskModel] = field(default_factory=dict)
    checked_tasks: dict[tuple[str, int], list[str]] = field(default_factory=dict)
    extra_checks: dict[str, Callable] = field(default_factory=dict)
    """Witness type -> check(case, model) -> list of reasons, from plugin operators."""
    extra_types: dict[str, str] = field(default_factory=dict)
    """Family -> witness type, for families plugins add."""

    def model(self, key: tuple[str, int]) -> TaskModel:
        if key not in self.models:
            self.models[key] = build_model(base_task(*key), self.facts[key])
        return self.models[key]


def new_context(facts_path=None, operators: Iterable = ()) -> Context:
    ctx = Context(load_scene_facts(facts_path))
    for spec in operators:
        if getattr(spec, "check", None) and getattr(spec, "witness_type", None):
            ctx.extra_checks[spec.witness_type] = spec.check
            ctx.extra_types.setdefault(spec.family, spec.witness_type)
    return ctx


# -- base task ------------------------------------------------------------------------------------
def _task_problems(ctx: Context, key: tuple[str, int]) -> list[str]:
    if key in ctx.checked_tasks:
        return ctx.checked_tasks[key]
    from conflictbench.tasks.libero.base_tasks import load_init_states

    out: list[str] = []
    facts = ctx.facts.get(key)
    task = base_task(*key)
    if facts is None:
        out.append(f"no scene facts for {key[0]} task {key[1]}")
    else:
        if file_sha256(task.bddl_path) != facts.bddl_sha256:
            out.append(f"the base task's BDDL file changed since its scene facts were derived ({task.bddl_path})")
        if states_sha256(load_init_states(*key)) != facts.init_states_sha256:
            out.append("the base task's fixed initial states changed since its scene facts were derived")
        entities = set(task.problem.objects) | set(task.problem.fixtures) | set(task.problem.regions)
        missing = sorted({a for atom in task.goal for a in atom[1:]} - entities)
        if missing:
            out.append(f"the base task's goal names unknown entities: {', '.join(missing)}")
        met = facts.states()
        for atom in task.goal:
            met = met & facts.predicate(*atom)
        if met:
            out.append(f"the base task's goal already holds in initial state(s) {sorted(met)[:5]}")
    ctx.checked_tasks[key] = out
    return out


# -- names in text --------------------------------------------------------------------------------
def entity_names(model: TaskModel, entity: str) -> set[str]:
    return model.entity_names(entity)


def names_in(text: str, names: Iterable[str]) -> bool:
    t = f" {normalise(text)} "
    return any(f" {normalise(n)} " in t for n in names)


def _named_or_pronoun(model: TaskModel, entity: str, text: str, instruction: str) -> bool:
    names = entity_names(model, entity)
    if names_in(text, names):
        return True
    return bool(PRONOUNS & set(words(text))) and names_in(instruction, names)


# -- family rules ---------------------------------------------------------------------------------
def check_contradiction(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    w, out = case.witness, []
    reqs = {r.get("id"): r for r in w.get("requirements", []) if isinstance(r, dict)}
    for r in reqs.values():
        lit = r.get("literal")
        if not isinstance(lit, list) or len(lit) < 3 or lit[0] not in ("goal", "avoid", "keep", "do"):
            out.append(f"requirement {r.get('id')}: malformed literal {lit!r}")
            continue
        if r.get("text", "") not in case.instruction:
            out.append(f"requirement {r.get('id')}: text {r.get('text')!r} is not in the instruction")
        for e in literal_entities(lit):
            if e not in model.facts.entities and e not in model.problem.fixtures:
                out.append(f"requirement {r.get('id')}: {e!r} is not in the scene")
            elif not _named_or_pronoun(model, e, r.get("text", ""), case.instruction):
                out.append(f"requirement {r.get('id')}: its text does not name {e}")
    if not w.get("conflicts"):
        out.append("the witness lists no contradicting requirements")
    for pair in w.get("conflicts", []):
        if not (isinstance(pair, list) and len(pair) == 2 and all(p in reqs for p in pair)):
            out.append(f"conflict {pair!r} does not name two listed requirements")
            continue
        a, b = (reqs[p].get("literal") for p in pair)
        if (
            isinstance(a, list)
            and isinstance(b, list)
            and len(a) >= 3
            and len(b) >= 3
            and contradiction(a, b, model.facts, states) is None
        ):
            out.append(f"requirements {pair[0]} and {pair[1]} do not contradict ({a} / {b})")
    return out


def check_absent(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    for r in case.witness.get("referents", []):
        text = str(r.get("text", ""))
        if not text or text not in case.instruction:
            out.append(f"referent {text!r} is not in the instruction")
            continue
        known = absent_concept(str(r.get("concept", "")))
        synonyms = known.synonyms if known else ()
        phrase = text.removeprefix("the ")
        why = absence_problem(phrase, synonyms, model.problem)
        if why:
            out.append(f"referent {text!r} is not absent: {why}")
    return out


def check_relation(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    facts = model.facts
    for r in case.witness.get("relations", []):
        rel, text = r.get("relation"), str(r.get("text", ""))
        if rel not in RELATIONS:
            out.append(f"unknown relation {rel!r}")
            continue
        if text not in case.instruction:
            out.append(f"relation text {text!r} is not in the instruction")
        args = [r.get("subject", {})] + list(r.get("landmarks", []))
        if len(args) != (3 if rel == "between" else 2):
            out.append(f"{rel} takes {3 if rel == 'between' else 2} arguments, got {len(args)}")
            continue
        groups = []
        for arg in args:
            listed = set(arg.get("entities", []))
            unknown = listed - set(facts.entities)
            if not listed or unknown:
                out.append(f"relation {rel}: entities {sorted(unknown) or '(none)'} are not in the scene")
                break
            missing = model.candidates(str(arg.get("phrase", ""))) - listed
            if missing:
                out.append(f"relation {rel}: {arg.get('phrase')!r} could also mean {', '.join(sorted(missing))}")
            if not names_in(text, {str(arg.get("phrase", ""))}):
                out.append(f"relation text {text!r} does not name {arg.get('phrase')!r}")
            groups.append(sorted(listed))
        else:
            if not any(names_in(text, {w}) for w in RELATION_WORDS[rel]):
                out.append(f"relation text {text!r} does not say {rel.replace('_', ' ')}")
            for combo in _product(groups):
                true_in = facts.holds(rel, *combo) & states
                if true_in:
                    out.append(f"{rel}{tuple(combo)} holds in initial state(s) {sorted(true_in)[:5]}")
    return out


def _product(groups: list[list[str]]) -> list[list[str]]:
    combos: list[list[str]] = [[]]
    for g in groups:
        combos = [c + [x] for c in combos for x in g if x not in c]
    return combos


def check_affordance(case: ConflictCase, model: TaskModel, states: frozenset) -> list[str]:
    out = []
    present = set(model.problem.objects) | set(model.problem.fixtures)
    for v in case.witness.get("violations", []):
        entity, needs, text = v.get("entity"), v.get("needs"), str(v.get("text", ""))
        if entity not in present:
            out.append(f"violation: {entity!r} is not in the scene")
            continue
        if needs not in NEEDS:
            out.append(f"violation: unknown affordance {needs!r}")
            continue
        if text not in case.instruction:
            out.append(f"violation text {text!r} is not in the instruction")
        info = category(model.category_of(entity))
        if needs == "fits_in":
            holder = v.get("holder")
            if holder not in present:
                out.append(f"violation: holder {holder!r} is not in the scene")
                continue
            if fits_inside(info.category, model.category_of(holder)) is not False:
                out.append(f"{entity} may fit inside {holder}")
            if not names_in(text, entity_names(model, holder)) or not names_in(
                case.instruction, entity_names(model, entity)
            ):
                out.append(f"the text does not name {entity} and {holder}")
            continue
        violated = info.has("fixed") is True if needs == "movable" else info.lacks(needs)
        if not violated:
            out.append(f"{entity} ({info.category}) does not plainly lack {needs!r} in the affordance table")
        if not names_in(text, entity_names(model, entity)):
            out.append(f"violation text {text!r} does not name {entity}")
    return out


FAMILY_CHECKS = {
    "contradiction": check_contradiction,
    "absent_referent": check_absent,
    "false_relation": check_relation,
    "affordance_violation": check_affordance,
}


# -- one case, a whole suite ----------------------------------------------------------------------
def _structure(case: ConflictCase, wtype: str) -> list[str]:
    w, out = case.witness, []
    steps = w.get("steps")
    if not isinstance(steps, list) or not steps or not all(isinstance(s, str) and s for s in steps):
        return ["witness field 'steps' must list the instruction's steps"]
    pos = 0
    for s in steps:
        i = case.instruction.find(s, pos)
        if i < 0:
            out.append(f"step {s!r} is not in the instruction (in order)")
            break
        pos = i + len(s)
    factors = w.get(FACTOR_KEYS.get(wtype, "factors"), [])
    if not isinstance(factors, list) or not factors:
        return out + [f"witness field {FACTOR_KEYS.get(wtype, 'factors')!r} is empty"]
    if wtype == "contradiction":
        step_of = {r.get("id"): r.get("step") for r in w.get("requirements", []) if isinstance(r, dict)}
        factor_steps = [max(step_of.get(p, 0) or 0 for p in pair) if isinstance(pair, list) else 0 for pair in factors]
    else:
        factor_steps = [f.get("step") if isinstance(f, dict) else None for f in factors]
    if not all(isinstance(s, int) and 1 <= s <= len(steps) for s in factor_steps):
        out.append(f"factor steps {factor_steps} do not point at the {len(steps)} step(s)")
    n, k, spread = len(steps), len(factors), len(set(factor_steps))
    expected = {
        "L1": n == 1 and k == 1,
        "L2": n == 1 and k >= 2,
        "L3": n >= 2 and k == 1,
        "L4": n >= 2 and k >= 2 and spread >= 2,
    }
    if not expected.get(case.level, False):
        out.append(f"level {case.level} does not match the witness ({n} step(s), {k} factor(s) in {spread} step(s))")
    return out


def validate_case(case: ConflictCase, ctx: Context) -> list[str]:
    key = (case.suite, case.task_id)
    try:
        task = base_task(*key)
    except Exception as exc:  # an unknown task id is a finding, not a crash
        return [str(exc)]
    out = list(_task_problems(ctx, key))
    if key not in ctx.facts:
        return out
    if case.base_instruction != task.language:
        out.append(
            f"base_instruction {case.base_instruction!r} is not the task's reference instruction {task.language!r}"
        )
    if normalise(case.instruction) == normalise(task.language):
        out.append("the instruction equals the base instruction")
    wtype = WITNESS_TYPES.get(case.family) or ctx.extra_types.get(case.family)
    if case.witness.get("type") != wtype:
        return out + [
            f"witness type {case.witness.get('type')!r} does not fit family {case.family!r} (expected {wtype!r})"
        ]
    model = ctx.model(key)
    states = model.facts.states()
    if case.init_states is not None:
        bad = [s for s in case.init_states if s not in states]
        if bad or not case.init_states:
            return out + [
                f"init_states {list(case.init_states)[:5]} are not among the task's {model.facts.n_states} states"
            ]
        states = frozenset(case.init_states)
    try:  # a witness from a user's file may have any shape: a bad one is a finding, not a crash
        if wtype in FAMILY_CHECKS:
            out += _structure(case, wtype)
            out += FAMILY_CHECKS[wtype](case, model, states)
        else:
            out += list(ctx.extra_checks[wtype](case, model))
    except (AttributeError, TypeError, KeyError, ValueError, IndexError) as exc:
        out.append(f"malformed witness ({type(exc).__name__}: {exc})")
    return out


def validate_cases(cases: Iterable[ConflictCase], ctx: Context) -> list[tuple[str, str]]:
    """(case_id, reason) for every rule a case breaks; removed cases are skipped."""
    failures: list[tuple[str, str]] = []
    seen: dict[tuple[str, int, str], str] = {}
    for case in cases:
        if case.status == "removed":
            continue
        for reason in validate_case(case, ctx):
            failures.append((case.case_id, reason))
        key = (case.suite, case.task_id, normalise(case.instruction))
        if key in seen:
            failures.append((case.case_id, f"same instruction as {seen[key]} for the same base task"))
        seen.setdefault(key, case.case_id)
    return failures
