"""What the main process and a simulator worker say to each other: typed records, one class per message.

Main process -> worker: :class:`Play` an episode, answer each :class:`Query` with :class:`Actions`
or :class:`Abort`, and finally :class:`Stop`. Worker -> main process: :class:`Ready` (or
:class:`Fatal`) once at start, then per episode any number of :class:`Query` and one :class:`Done`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from conflictbench.core import ACTION_DIM, ConflictCase, EpisodeRecord, Observation


@dataclass(frozen=True)
class EpisodeJob:
    """Everything a worker needs to play one planned episode."""

    episode_id: str
    suite: str
    task_id: int
    bddl_path: str
    init_state: int
    seed: int
    instruction: str
    """The prompt text the policy gets (also handed over in every observation)."""
    goal: tuple[tuple[str, ...], ...]
    targets: tuple[str, ...]
    warmup_steps: int
    max_steps: int
    needs_privileged: bool
    case: ConflictCase | None = None
    needs_scene_state: bool = False
    stream: int = 0
    sampling_key: str = ""
    """Seeds a sampling policy's draws (``Observation.sampling_key``): the episode's id without the code digest."""
    control_mode: str = "relative"
    """How the arm reads actions after the warm-up (:attr:`conflictbench.core.PolicyTraits.control_mode`)."""


@dataclass(frozen=True)
class EpisodeOutcome:
    """What playing an episode produced. Every field is an :class:`EpisodeRecord` field of the same name."""

    success: bool
    steps: int
    error: str | None
    eef_pos: np.ndarray
    """(H+1, 3)"""
    target_pos: np.ndarray
    """(H+1, K, 3)"""
    actions: np.ndarray
    """(H, 7) executed"""
    raw_actions: np.ndarray
    """(H, 7) as the policy returned them"""
    sim_time_s: float | None
    """Seconds the worker spent simulating, not waiting for the policy (``None``: not measured)."""
    error_kind: str | None = None
    """Whose failure ended it (``ERROR_KINDS``) where ``error`` is set."""
    sim_warnings: tuple[str, ...] = ()
    """MuJoCo's warnings during the episode (``mjWARN_BADQACC x2``: an unstable simulation MuJoCo reset)."""

    @classmethod
    def failed(cls, error: str, kind: str, targets: int) -> EpisodeOutcome:
        """An episode that ended before any state was recorded (the policy's reset raised, the worker died)."""
        return cls(
            success=False,
            steps=0,
            error=error,
            error_kind=kind,
            eef_pos=np.zeros((0, 3)),
            target_pos=np.zeros((0, targets, 3)),
            actions=np.zeros((0, ACTION_DIM)),
            raw_actions=np.zeros((0, ACTION_DIM)),
            sim_time_s=None,
        )

    def record_fields(self) -> dict[str, Any]:
        """The outcome as keyword arguments of :class:`EpisodeRecord`."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}


_RECORD_FIELDS = {f.name for f in dataclasses.fields(EpisodeRecord)}
assert {f.name for f in dataclasses.fields(EpisodeOutcome)} <= _RECORD_FIELDS, (
    "every EpisodeOutcome field must be an EpisodeRecord field (and so a store column)"
)


# -- worker -> main process ------------------------------------------------------------------
@dataclass(frozen=True)
class Ready:
    """The simulator imported; this is its stack (``stack.stack_probe``: recorded with every episode)."""

    versions: dict[str, str]


@dataclass(frozen=True)
class Fatal:
    """The worker cannot simulate at all; the run stops with this message."""

    message: str


@dataclass(frozen=True)
class Query:
    """The policy must decide: here is what it sees."""

    observation: Observation


@dataclass(frozen=True)
class Done:
    outcome: EpisodeOutcome


# -- main process -> worker ------------------------------------------------------------------
@dataclass(frozen=True)
class Play:
    job: EpisodeJob


@dataclass(frozen=True)
class Actions:
    """The answer to a :class:`Query`: a chunk to execute open-loop, as returned and as post-processed."""

    raw: np.ndarray
    executed: np.ndarray


@dataclass(frozen=True)
class Abort:
    """The answer to a :class:`Query` when the policy failed: the episode ends with this error."""

    reason: str
    kind: str = "policy"
    """Whose failure it is (``ERROR_KINDS``): decided where it was raised."""


@dataclass(frozen=True)
class Stop:
    """Leave the worker loop and close the environment."""
