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
from conflictbench.tasks.scene.facts import TaskFacts, file_sha256, load_scene_facts, states_sha256
from conflictbench.tasks.scene.task_model import TaskModel, build_model

from .factors import components_missing
from .grounding import check_absent
from .instruction import check_contradiction
from .physical import check_affordance
from .spatial import check_relation
from .structure import check_structure
from .suite_rules import suite_problems
from .text import normalise

WITNESS_TYPES = {
    "instruction": "contradiction",
    "grounding": "absent_referent",
    "spatial": "false_relation",
    "physical": "affordance_violation",
}


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


# -- family rules ---------------------------------------------------------------------------------
FAMILY_CHECKS = {
    "contradiction": check_contradiction,
    "absent_referent": check_absent,
    "false_relation": check_relation,
    "affordance_violation": check_affordance,
}


# -- one case, a whole suite ----------------------------------------------------------------------
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
            out += check_structure(case, wtype, model) + components_missing(case.level, case.witness)
            out += FAMILY_CHECKS[wtype](case, model, states)
        else:
            out += list(ctx.extra_checks[wtype](case, model))
    except (AttributeError, TypeError, KeyError, ValueError, IndexError) as exc:
        out.append(f"malformed witness ({type(exc).__name__}: {exc})")
    return out


def validate_cases(cases: Iterable[ConflictCase], ctx: Context, *, composition: bool = True) -> list[tuple[str, str]]:
    """(case_id, reason) for every rule a case breaks, then the rules about the suite as a whole
    (:mod:`.suite_rules`; ``composition=False`` for a part of a suite, such as an export); removed
    cases are skipped."""
    cases = [c for c in cases if c.status != "removed"]
    failures: list[tuple[str, str]] = []
    for case in cases:
        for reason in validate_case(case, ctx):
            failures.append((case.case_id, reason))
    return failures + suite_problems(cases, ctx, composition=composition)
