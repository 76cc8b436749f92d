"""The plan of a run: which episodes to play, references deduplicated, and their identities.

A conflict episode is (case, init state, prompt condition); every one of them needs the
reference episode of its (base task, init state, prompt condition), which all cases of that base
task share. An episode is stored under :func:`episode_id`, which covers :func:`config_hash`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import random
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from conflictbench.core import ConflictCase, PolicyTraits, UserError
from conflictbench.tasks.suite.file import USABLE

from .libero_env import simulator_versions


@dataclass(frozen=True)
class EpisodeSpec:
    """One planned episode (its identity; the policy's settings come from the run)."""

    suite: str
    task_id: int
    init_state: int
    prompt: str
    base_instruction: str
    case: ConflictCase | None = None
    conflict_suite: str = ""
    """``name version`` of the suite the case comes from (``conflictvla 2.1.0``); empty for a reference, which no
    suite changes. Part of a conflict episode's identity: a new suite version plays its cases again."""

    @property
    def instruction(self) -> str:
        return self.case.instruction if self.case else self.base_instruction

    @property
    def case_id(self) -> str | None:
        return self.case.case_id if self.case else None

    @property
    def task_key(self) -> tuple[str, int]:
        return (self.suite, self.task_id)

    @property
    def reference_key(self) -> tuple[str, int, int, str]:
        return (self.suite, self.task_id, self.init_state, self.prompt)


def episode_id(*, policy: str, config_hash: str, spec: EpisodeSpec, prompt_text: str, seed: int) -> str:
    """A stable name for an episode: the same inputs always map to the same stored row."""
    key = [
        policy,
        config_hash,
        spec.suite,
        spec.task_id,
        spec.init_state,
        spec.prompt,
        spec.case_id,
        spec.instruction,
        prompt_text,
        seed,
    ]
    if spec.conflict_suite:  # references' ids are as before the suite counted
        key.append(spec.conflict_suite)
    return hashlib.sha256(json.dumps(key).encode()).hexdigest()[:24]


def identity_settings(config: Any) -> dict[str, Any] | None:
    """A policy's settings that are part of its identity (a served policy's address and timeouts are not);
    None for a policy without settings (as hashed since the first store: episode ids must not move)."""
    if config is None:
        return None
    settings = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else dict(config)
    for name in getattr(config, "identity_exempt", ()):
        settings.pop(name, None)
    return settings


def settings_json(config: Any) -> str:
    """:func:`identity_settings` as the store keeps them (``policy_settings``)."""
    return json.dumps(identity_settings(config), sort_keys=True, default=repr)


def config_hash(
    policy: str, config: Any, traits: PolicyTraits, code: tuple[str, ...] = (), simulator: dict[str, str] | None = None
) -> str:
    """Identifies everything besides the episode itself that can change a rollout: the policy, its
    settings and declared traits, the code behind it (``code``: ``distribution==version files=DIGEST`` of
    the conflictbench modules its rollout runs, the policy's plugin, every plugin implementing a global per-episode
    hook and the conflictbench distributions they require, see ``code_identity.code_pins``) and the
    simulator stack (``simulator``: what a worker's ``stack.stack_probe`` said, the renderer included for a policy
    that sees images; default: the simulator's versions here; a store never mixes MuJoCo versions)."""
    settings = identity_settings(config)  # a served policy's address and timeouts are not (ServingConfig)
    blob = json.dumps(
        {
            "policy": policy,
            "config": settings,
            "traits": traits.as_dict(),
            "code": list(code),
            "simulator": simulator if simulator is not None else simulator_versions(),
        },
        sort_keys=True,
        default=repr,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def named_cases(cases: Sequence[ConflictCase], case_ids: Sequence[str], selected) -> list[ConflictCase]:
    """The cases ``run.cases`` names, in the suite's order; one line for an id that is not there or not playable."""
    import difflib

    by_id = {c.case_id: c for c in cases}
    for case_id in case_ids:
        case = by_id.get(case_id)
        if case is None:
            close = difflib.get_close_matches(case_id, list(by_id), n=1, cutoff=0.5)
            hint = f"; the closest is {close[0]}" if close else f" (ids look like {next(iter(by_id), '?')})"
            raise UserError(f"run.cases: no case {case_id!r} in the suite{hint}")
        if case.status not in USABLE:
            raise UserError(f"run.cases: case {case_id} was {case.status} by the suite's validation; it is not played")
        if not selected(case):
            raise UserError(
                f"run.cases: case {case_id} ({case.family} {case.level}, {case.suite}/{case.task_id}) is outside "
                "this selection (suite=, level=, run.libero_suites, run.tasks)"
            )
    wanted = set(case_ids)
    return [c for c in cases if c.case_id in wanted]


def sample_cases(cases: Sequence[ConflictCase], per_cell: int | None, seed: int) -> list[ConflictCase]:
    """At most ``per_cell`` cases per (family, level) cell: a seeded sample stratified over LIBERO suites.

    Within a cell the suites take turns (in a seeded order), so a small sample still spans suites.
    ``None`` keeps every case.
    """
    if per_cell is None:
        return sorted(cases, key=lambda c: c.case_id)
    cells: dict[tuple[str, str], list[ConflictCase]] = defaultdict(list)
    for case in cases:
        cells[(case.family, case.level)].append(case)
    chosen: list[ConflictCase] = []
    for cell in sorted(cells):
        rng = random.Random(f"{seed}:{cell[0]}:{cell[1]}")
        by_suite: dict[str, list[ConflictCase]] = defaultdict(list)
        for case in sorted(cells[cell], key=lambda c: c.case_id):
            by_suite[case.suite].append(case)
        order = sorted(by_suite)
        rng.shuffle(order)
        for group in by_suite.values():
            rng.shuffle(group)
        picked: list[ConflictCase] = []
        while len(picked) < per_cell and any(by_suite.values()):
            for suite in order:
                if by_suite[suite] and len(picked) < per_cell:
                    picked.append(by_suite[suite].pop())
        chosen.extend(picked)
    return sorted(chosen, key=lambda c: c.case_id)


def build_plan(
    cases: Iterable[ConflictCase],
    *,
    base_instructions: dict[tuple[str, int], str],
    families: Sequence[str],
    levels: Sequence[str],
    prompts: Sequence[str],
    init_states: Sequence[int],
    cases_per_cell: int | None,
    sample_seed: int = 0,
    libero_suites: Sequence[str] | None = None,
    case_ids: Sequence[str] | None = None,
    base_tasks: Sequence[tuple[str, int]] | None = None,
    conflict_suite: str = "",
) -> list[EpisodeSpec]:
    """Conflict episodes for the sampled cases plus the references they need, grouped by base task.

    ``base_instructions`` maps every usable (suite, task_id) to its reference instruction; with
    ``cases_per_cell == 0`` the plan holds only the references of those base tasks. ``base_tasks``
    keeps only those base tasks (``run.tasks``); ``case_ids`` plays exactly those cases
    (``run.cases``: no sample), each of which must be in the selection the other filters make.
    ``conflict_suite`` (``name version``) marks the conflict episodes as the suite's.
    """
    if cases_per_cell is not None and cases_per_cell < 0:
        raise UserError(f"run.cases_per_cell must be >= 0 or 'all', got {cases_per_cell}")
    if base_tasks is not None:
        base_instructions = _only_tasks(base_instructions, base_tasks)
    suites = set(libero_suites) if libero_suites else {s for s, _ in base_instructions}

    def selected(c: ConflictCase) -> bool:
        return (
            c.family in families
            and c.level in levels
            and c.suite in suites
            and (c.suite, c.task_id) in base_instructions
        )

    cases = list(cases)
    if case_ids is not None:
        chosen = named_cases(cases, case_ids, selected)
    else:
        eligible = [c for c in cases if c.status in USABLE and selected(c)]
        chosen = [] if cases_per_cell == 0 else sample_cases(eligible, cases_per_cell, sample_seed)
    conflicts = _conflict_episodes(chosen, base_instructions, init_states, prompts, conflict_suite)
    reference_keys = {spec.reference_key for spec in conflicts}
    if cases_per_cell == 0:
        reference_keys = {
            (s, t, i, p) for (s, t) in base_instructions if s in suites for i in init_states for p in prompts
        }
    references = [EpisodeSpec(s, t, i, p, base_instructions[(s, t)]) for (s, t, i, p) in reference_keys]
    # Group by base task (a worker keeps its env between episodes of one task), references first.
    return sorted(
        references + conflicts,
        key=lambda e: (e.suite, e.task_id, e.case is not None, e.case_id or "", e.init_state, e.prompt),
    )


def _only_tasks(base_instructions: dict[tuple[str, int], str], base_tasks: Sequence[tuple[str, int]]) -> dict:
    """The base instructions of ``run.tasks`` alone; each of them must be among the usable ones."""
    wanted = set(base_tasks)
    kept = {key: text for key, text in base_instructions.items() if key in wanted}
    left_out = sorted(wanted - set(kept))
    if left_out:
        raise UserError(f"run.tasks names {', '.join(f'{s}/{t}' for s, t in left_out)}, outside run.libero_suites")
    return kept


def _conflict_episodes(
    chosen: list[ConflictCase],
    base_instructions: dict[tuple[str, int], str],
    init_states: Sequence[int],
    prompts: Sequence[str],
    conflict_suite: str,
) -> list[EpisodeSpec]:
    """Each chosen case in each of its initial states (those of the run it allows) and each prompt."""
    conflicts = []
    for case in chosen:
        states = [s for s in init_states if case.init_states is None or s in case.init_states]
        base = base_instructions[(case.suite, case.task_id)]
        for state in states:
            for prompt in prompts:
                conflicts.append(EpisodeSpec(case.suite, case.task_id, state, prompt, base, case, conflict_suite))
    return conflicts
