"""What a run plays, decided before anything starts: its episodes' identity, and which of them are left to play.

The identity (:func:`run_identity`) covers the policy, its settings and traits, the code by content, the model stack
a served model declares and the simulator's versions (``plan.config_hash``); sampling is seeded by the same identity
with the code by versions, so an edit that changes no action draws the same noise. What is left to play
(:func:`left_to_play`) is what the store lacks, less what failed twice the same way (unless ``run.retry``); where
stored episodes of the same settings were played under another identity, one line says what changed.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from typing import Any

from conflictbench.core import PolicyTraits
from conflictbench.core.plugins import Plugins
from conflictbench.store.episodes import EpisodeStore

from .code_identity import code_identity
from .episode_rows import stack_pins
from .identity_change import identity_changes, keep_manifests
from .plan import config_hash, settings_json
from .slots import Item
from .stack import simulator_columns

CHANGED = "this policy's newest episodes in the store were played under another identity and are not reused"


@dataclass
class RunResult:
    planned: int = 0
    already_stored: int = 0
    played_elsewhere: int = 0
    """Episodes another job sharing the store was playing when this one reached them."""
    played: int = 0
    replayed_after_loss: int = 0
    """Episodes played again because their worker was lost mid-episode."""
    succeeded: int = 0
    errors: int = 0
    failed_twice: int = 0
    """Episodes left waiting: their last two attempts failed the same way, not by the policy (``retry``)."""
    episode_ids: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class RunIdentity:
    """What identifies a run's episodes (each episode's id adds the episode itself: ``plan.episode_id``)."""

    config_hash: str
    sampling_hash: str
    """``config_hash`` with the code by ``distribution==version``: seeds sampling (``Observation.sampling_key``)."""
    code_versions: tuple[str, ...]
    model_stack: tuple[str, ...]
    stack: dict[str, str] = field(default_factory=dict)
    """The simulator's stack (``stack.stack_probe``) the run's workers must all have."""
    policy_identity: str = ""
    """The policy's declared ``identity`` but the model stack, as JSON (``EpisodeRecord.policy_identity``)."""
    manifests: dict[str, dict[str, str]] = field(default_factory=dict)
    """Each code pin's files and their digests (kept in the store to say which files changed)."""


def identity_json(identity: dict[str, Any]) -> str:
    """A policy's declared identity as the store keeps it: JSON, sorted, without the model stack (its own column)."""
    rest = {key: value for key, value in identity.items() if key != "model_stack"}
    return json.dumps(rest, sort_keys=True, default=repr) if rest else ""


def run_identity(
    plugins: Plugins, policy: str, config: Any, traits: PolicyTraits, stack: dict[str, str]
) -> RunIdentity:
    """``stack``: what a worker's probe said (``stack.probe_in_worker``), the renderer included where images count."""
    versions = plugins.provenance(policy)
    code_versions, manifests = code_identity(versions, plugins.policy(policy))  # the code by content: what it runs
    return RunIdentity(
        config_hash=config_hash(policy, config, traits, code_versions, stack),
        sampling_hash=config_hash(policy, config, traits, versions, simulator_columns(stack)),
        stack=dict(stack),
        code_versions=code_versions,
        model_stack=stack_pins(traits.identity.get("model_stack")),  # in config_hash through the traits
        policy_identity=identity_json(traits.identity),
        manifests=manifests,
    )


def left_to_play(
    store: EpisodeStore, items: list[Item], identity: RunIdentity, policy: str, config: Any, retry: bool
) -> tuple[list[Item], RunResult]:
    """The planned episodes the store lacks, less those that failed twice the same way (``retry`` plays them); says
    why in one line where the policy's newest stored episodes of these settings were played under another
    identity."""
    result = RunResult(planned=len(items), episode_ids=[i.job.episode_id for i in items])
    store.set_aside_damaged(result.episode_ids)  # names only below: a damaged file must not count as stored
    stored = store.stored_ids()
    todo = [i for i in items if i.job.episode_id not in stored]
    result.already_stored = len(items) - len(todo)
    keep_manifests(store.root, identity.manifests)
    settings = settings_json(config)
    if todo and (changed := identity_changes(store, policy, identity.config_hash, identity.code_versions, settings,
                                             identity.stack, identity.model_stack)):  # fmt: skip
        print(f"conflictbench: {CHANGED}: {'; '.join(changed)}", file=sys.stderr)
    if not retry and (repeated := store.repeated_failure_ids() & {i.job.episode_id for i in todo}):
        todo = [i for i in todo if i.job.episode_id not in repeated]
        result.failed_twice = len(repeated)
        print(
            f"conflictbench: {len(repeated)} episode(s) failed twice the same way, not by the policy, and are not "
            "played again (run.retry=true plays them)",
            file=sys.stderr,
        )
    return todo, result
