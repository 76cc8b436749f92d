"""From a plan to the workers' jobs, and from their outcomes to the store's rows (what the runner hands out and
keeps, apart from how it drives the workers): each episode's identity and prompt text, the time estimate from
earlier episodes, and the stored record with its provenance."""

from __future__ import annotations

import dataclasses
import datetime as _dt
from typing import Any

import pyarrow.compute as pc

from conflictbench.core import EpisodeRecord, PolicySpec, PolicyTraits
from conflictbench.core.plugins import Plugins
from conflictbench.store.episodes import EpisodeStore
from conflictbench.tasks.libero.base_tasks import base_task

from .messages import EpisodeJob, EpisodeOutcome
from .plan import EpisodeSpec, episode_id, settings_json
from .slots import Item
from .stack import extra_stack, simulator_columns

#: Episodes read at most for a fresh run's time estimate (the policy's latest in the store).
ESTIMATE_SAMPLE = 200


def make_items(
    plan: list[EpisodeSpec],
    traits: PolicyTraits,
    plugins: Plugins,
    policy: str,
    config_hash: str,
    seed: int,
    sampling_hash: str = "",
) -> list[Item]:
    """Each planned episode with its worker's job: the prompt text the policy gets, the episode's identity, the
    base task's files and targets, the policy's step budget. ``sampling_hash`` is ``config_hash`` by versions
    rather than code content: the episode's id under it seeds sampling (``EpisodeJob.sampling_key``)."""
    items = []
    for spec in plan:
        task = base_task(spec.suite, spec.task_id)
        text = plugins.format_prompt(spec.instruction, spec.prompt, policy)
        eid = episode_id(policy=policy, config_hash=config_hash, spec=spec, prompt_text=text, seed=seed)
        unversioned = dataclasses.replace(spec, conflict_suite="")  # the same draws for a case a new suite keeps
        key = episode_id(policy=policy, config_hash=sampling_hash, spec=unversioned, prompt_text=text, seed=seed)
        job = EpisodeJob(
            episode_id=eid,
            sampling_key=key if sampling_hash else "",
            suite=spec.suite,
            task_id=spec.task_id,
            bddl_path=task.bddl_path,
            init_state=spec.init_state,
            seed=seed,
            instruction=text,
            goal=task.goal,
            targets=task.targets,
            warmup_steps=traits.warmup_steps,
            max_steps=traits.max_steps[spec.suite],
            needs_privileged=traits.needs_privileged,
            needs_scene_state=traits.needs_scene_state,
            case=spec.case,
            control_mode=traits.control_mode,
        )
        items.append(Item(spec, job))
    return items


def seconds_each(
    store: EpisodeStore, items: list[Item], stored: set[str], policy: str, config_hash: str
) -> tuple[float | None, str]:
    """Mean wall time of this plan's episodes already stored; else of this policy's (same settings and
    code) elsewhere in the store, the last ``ESTIMATE_SAMPLE`` of them; None where there are none. With
    the basis, in words."""
    done = [i.job.episode_id for i in items if i.job.episode_id in stored]
    basis = "so far"
    if done:
        table = store.read_table(columns=["wall_time_s"], episode_ids=done)
    else:
        basis = "of its earlier episodes in this store"
        folder = store.episodes_dir / policy
        files = sorted(folder.glob("*.parquet"), key=lambda p: p.stat().st_mtime)[-ESTIMATE_SAMPLE:]
        if not files:
            return None, basis
        table = store.read_table(columns=["config_hash", "wall_time_s"], episode_ids=[f.stem for f in files])
        table = table.filter(pc.equal(table["config_hash"], config_hash))
    times = [t for t in table["wall_time_s"].to_pylist() if t]
    return (sum(times) / len(times) if times else None), basis


def stack_pins(stack: Any) -> tuple[str, ...]:
    """A policy's declared ``identity["model_stack"]`` as the store keeps it (``EpisodeRecord.model_stack``):
    ``device=KIND`` then each ``name==version``; ``("unreported",)`` for a server that does not say."""
    if isinstance(stack, dict):
        packages = stack.get("packages") or {}
        return (
            f"device={stack.get('device', '?')}",
            *(f"{name}=={version}" for name, version in sorted(packages.items())),
        )
    return (str(stack),) if stack else ()


def episode_record(
    item: Item,
    outcome: EpisodeOutcome,
    *,
    spec: PolicySpec,
    config: Any,
    config_hash: str,
    code_versions: tuple[str, ...],
    simulator: dict[str, str],
    wall_time_s: float,
    model_stack: tuple[str, ...] = (),
    policy_identity: str = "",
) -> EpisodeRecord:
    """The stored row: the episode's keys and provenance from the run, the rest from the worker's outcome."""
    planned, job = item.spec, item.job
    case = planned.case
    return EpisodeRecord(
        policy=spec.name,
        suite=planned.suite,
        task_id=planned.task_id,
        init_state=planned.init_state,
        prompt=planned.prompt,
        instruction=planned.instruction,
        seed=job.seed,
        case_id=planned.case_id,
        family=case.family if case else None,
        level=case.level if case else None,
        episode_id=job.episode_id,
        conflict_suite=planned.conflict_suite or None,
        base_instruction=planned.base_instruction,
        prompt_text=job.instruction,
        max_steps=job.max_steps,
        warmup_steps=job.warmup_steps,
        control_mode=job.control_mode,
        target_names=job.targets,
        conflictbench_version=_own_version(),
        plugin=spec.plugin,
        plugin_version=spec.plugin_version,
        code_versions=code_versions,
        model_stack=model_stack,
        policy_identity=policy_identity,
        config_hash=config_hash,
        policy_settings=settings_json(config),
        created_at=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        wall_time_s=wall_time_s,
        **simulator_columns(simulator),
        sim_stack=extra_stack(simulator),
        **outcome.record_fields(),
    )


def _own_version() -> str:
    import conflictbench

    return conflictbench.__version__
