"""Building the conflict suite: operators over base tasks, selection, ids, review, validation.

Deterministic: every random choice comes from a ``random.Random`` seeded with the build seed and
the (task, family, level, operator) it serves, so the same seed writes a byte-identical file and
adding one operator does not reshuffle the cases of the others.
"""

from __future__ import annotations

import hashlib
import random
from collections import defaultdict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from conflictbench.core import FAMILIES, LEVELS, LIBERO_SUITES, ConflictCase, PluginError
from conflictbench.tasks.libero.base_tasks import all_base_tasks
from conflictbench.tasks.operators import builtin_operators
from conflictbench.tasks.operators.frames import Draft
from conflictbench.tasks.scene.facts import load_scene_facts
from conflictbench.tasks.scene.task_model import TaskModel, build_model
from conflictbench.tasks.suite.file import format_suite
from conflictbench.tasks.suite.review import apply_reviews, load_reviews
from conflictbench.tasks.validation.factors import bears_on, with_components
from conflictbench.tasks.validation.rules import Context, new_context, normalise, validate_case

SUITE_NAME = "conflictvla"
SUITE_VERSION = "2.1.0"
"""Bumped whenever a case's text changes (2.0.0: every conflict observable, whole originals, truly
unsatisfiable contradictions, camera-visible spatial margins, broader grounding and physical families,
every case reviewed; 2.1.0: a step is a manipulation with its own goal, L4's factors distinct and
said per component, directions false between footprints and flagged for the robot's frame, added
steps that claim nothing false)."""
DEFAULT_SEED = 0
PER_CELL = {
    "instruction": 3,
    "grounding": 3,
    "spatial": 3,
    "physical": 3,
    "grounding/L2": 4,
    "spatial/L1": 4,
    "spatial/L2": 4,
    "physical/L1": 4,
    "physical/L2": 6,
}
"""Cases kept per (base task, family, level); ``family/level`` overrides a family's number for one
level; fewer where a task offers fewer valid candidates. Since suite 2.1 only the 30 base tasks of
one manipulation have a single-step frame, and in the single-step cells where fewer than three of
them offer valid candidates, three each would leave the cell a few review removals from 80: those
take four (physical L2 six: only 16 one-step tasks offer two violations that each stand alone, once
a too-small holder is a step of its own rather than a manner). Raising a number only appends cases:
the selection picks in the same order."""
MAX_CANDIDATES = 400
"""Candidates drawn per (task, family, level, operator) before selection: bounds build time."""
SUITE_ABBREV = {"libero_spatial": "spa", "libero_object": "obj", "libero_goal": "goal", "libero_10": "l10"}
FAMILY_ABBREV = {"instruction": "ins", "grounding": "gro", "spatial": "spa", "physical": "phy"}


@dataclass(frozen=True)
class OperatorEntry:
    name: str
    family: str
    generate: Callable[..., Iterable[Any]]
    levels: tuple[str, ...] = LEVELS


def operator_entries(plugins=None) -> list[OperatorEntry]:
    """Built-in operators, or every registered one (built-ins register through the same hook)."""
    if plugins is None:
        return [OperatorEntry(n, f, g) for n, f, g in builtin_operators()]
    return [OperatorEntry(s.name, s.family, s.generate, tuple(s.levels)) for s in plugins.conflict_operators().values()]


def case_id(suite: str, task_id: int, family: str, level: str, instruction: str) -> str:
    digest = hashlib.sha256(f"{suite}|{task_id}|{family}|{level}|{instruction}".encode()).hexdigest()[:8]
    return f"{SUITE_ABBREV.get(suite, suite)}{task_id:02d}-{FAMILY_ABBREV.get(family, family[:3])}-{level}-{digest}"


def _as_draft(obj: Any, entry: OperatorEntry, level: str) -> Draft:
    """Operators may yield :class:`Draft` objects or plain dicts (plugins need not import ours)."""
    if isinstance(obj, Draft):
        return obj
    if isinstance(obj, dict):
        try:
            return Draft(
                family=obj.get("family", entry.family),
                level=obj.get("level", level),
                instruction=obj["instruction"],
                factors=tuple(obj.get("factors", ())),
                premise=obj.get("premise", ""),
                witness=dict(obj["witness"]),
                init_states=None if obj.get("init_states") is None else tuple(obj["init_states"]),
                operator=entry.name,
            )
        except KeyError as exc:
            raise PluginError(f"conflict operator {entry.name!r} yielded a draft without {exc}") from None
    raise PluginError(f"conflict operator {entry.name!r} yielded {type(obj).__name__}, expected a dict or Draft")


def _rng(seed: int, *parts: Any) -> random.Random:
    return random.Random(f"{seed}|" + "|".join(str(p) for p in parts))


def _select(drafts: list[Draft], k: int, rng: random.Random, accept: Callable[[Draft], bool]) -> list[Draft]:
    """Up to k drafts, spread over factor combinations and operators: round-robin over groups in a
    seeded order, each group shuffled; a draft that fails validation is skipped."""
    groups: dict[tuple, list[Draft]] = defaultdict(list)
    for d in drafts:
        groups[(d.operator, d.factors)].append(d)
    order = sorted(groups)
    rng.shuffle(order)
    for key in order:
        rng.shuffle(groups[key])
        groups[key].sort(key=_bearing)  # stable: bearing drafts last, so popped first
    order.sort(key=lambda g: not any(_bearing(d) for d in groups[g]))
    chosen: list[Draft] = []
    seen: set[str] = set()
    while len(chosen) < k and any(groups[g] for g in order):
        for g in order:
            while groups[g] and len(chosen) < k:
                d = groups[g].pop()
                if normalise(d.instruction) in seen or not accept(d):
                    continue
                seen.add(normalise(d.instruction))
                chosen.append(d)
                break
    return chosen


def _bearing(d: Draft) -> bool:
    """An L4 draft whose later step depends on what an earlier factor is about: preferred."""
    return d.level == "L4" and bears_on(with_components(d.witness))


def generate_task_cases(
    model: TaskModel,
    entries: Sequence[OperatorEntry],
    seed: int,
    ctx: Context,
    per_cell: dict[str, int] | None = None,
    taken: set[str] | None = None,
) -> list[ConflictCase]:
    task = model.task
    per_cell = per_cell or PER_CELL
    taken = taken if taken is not None else set()
    base = normalise(task.language)
    families = list(dict.fromkeys([*FAMILIES, *(e.family for e in entries)]))
    out: list[ConflictCase] = []
    for family in families:
        for level in LEVELS:
            drafts: list[Draft] = []
            for entry in entries:
                if entry.family != family or level not in entry.levels:
                    continue
                rng = _rng(seed, task.suite, task.task_id, family, level, entry.name)
                for i, obj in enumerate(entry.generate(model, level, rng)):
                    if i >= MAX_CANDIDATES:
                        break
                    d = _as_draft(obj, entry, level)
                    if (
                        d.family == family
                        and d.level == level
                        and normalise(d.instruction) != base
                        and normalise(d.instruction) not in taken
                    ):
                        drafts.append(d)

            def accept(d: Draft) -> bool:
                return not validate_case(_to_case(task, d), ctx)

            picked = _select(
                drafts,
                per_cell.get(f"{family}/{level}", per_cell.get(family, 3)),
                _rng(seed, task.suite, task.task_id, family, level),
                accept,
            )
            for d in picked:
                taken.add(normalise(d.instruction))
                out.append(_to_case(task, d))
    return out


def _to_case(task, d: Draft) -> ConflictCase:
    return ConflictCase(
        case_id=case_id(task.suite, task.task_id, d.family, d.level, d.instruction),
        suite=task.suite,
        task_id=task.task_id,
        base_instruction=task.language,
        instruction=d.instruction,
        family=d.family,
        level=d.level,
        factors=tuple(d.factors),
        premise=d.premise,
        witness=with_components(d.witness),
        status="accepted",
        init_states=d.init_states,
    )


def _sort_key(case: ConflictCase):
    fam = list(FAMILIES).index(case.family) if case.family in FAMILIES else len(FAMILIES)
    return (LIBERO_SUITES.index(case.suite), case.task_id, fam, case.family, case.level, case.case_id)


def build_cases(
    *,
    seed: int = DEFAULT_SEED,
    plugins=None,
    facts_path=None,
    reviews_path=None,
    per_cell: dict[str, int] | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[ConflictCase]:
    entries = operator_entries(plugins)
    ctx = new_context(facts_path, plugins.conflict_operators().values() if plugins is not None else ())
    facts = load_scene_facts(facts_path)
    cases: list[ConflictCase] = []
    taken: dict[str, set[str]] = defaultdict(set)  # no exact text twice within one LIBERO suite
    for task in all_base_tasks():
        if progress:
            progress(f"{task.suite} task {task.task_id}")
        model = build_model(task, facts[task.key])
        ctx.models[task.key] = model
        cases += generate_task_cases(model, entries, seed, ctx, per_cell, taken[task.suite])
    # The shipped decisions are about the shipped cases (seed 0); another seed writes other cases,
    # which nobody has reviewed yet, unless a decisions file for them is named. A case nobody has
    # decided on is pending: no run plays an unreviewed case.
    shipped = reviews_path is not None or seed == DEFAULT_SEED
    cases = apply_reviews(cases, load_reviews(reviews_path) if shipped else [], ctx, require_review=True)
    return sorted(cases, key=_sort_key)


def build_suite_text(**kwargs) -> str:
    seed = kwargs.get("seed", DEFAULT_SEED)
    cases = build_cases(**kwargs)
    return format_suite(cases, name=SUITE_NAME, version=SUITE_VERSION, extra={"seed": seed})
