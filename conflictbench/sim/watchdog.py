"""No run waits for ever: a bound on a worker's silence and on a policy call, and what passing one means.

A worker that says nothing for ``stall_s`` while its episode is not waiting for the policy (a frozen process,
a simulator stuck in a step, a node that stopped answering) is stopped and replaced; its episode is stored as a
``simulator`` failure, left out and played again by the next run, and the run goes on. A policy call still
running after ``call_s`` cannot be stopped (a thread cannot be killed): the run stops with one line
(:class:`PolicyStalled`), every finished episode stored, and the same command resumes.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

from conflictbench.core import PolicyStalled

__all__ = ["PolicyStalled", "StallWatch", "call_bound", "stall_bound"]

#: A worker may be silent this long at least: an env build (a scene's compile), a reset and a warm-up on a
#: loaded machine take well under a minute; a chunk of actions with cameras some seconds.
STALL_FLOOR_S = 300.0
#: ... plus this much per step of the longest step budget in the plan (a whole episode's chunk at worst).
SECONDS_PER_STEP = 1.0


def stall_bound(max_steps: Iterable[int]) -> float:
    """How long a worker may go without a message while it plays (derived from the step budget)."""
    return STALL_FLOOR_S + SECONDS_PER_STEP * max(max_steps, default=0)


def call_bound(config: Any, stall_s: float) -> float:
    """How long one policy call may run: ``stall_s``, and for a served policy at least what its transport may
    take before it gives up by itself (each send's timeout for the send and every resend, the connection
    retries with their backoff)."""
    timeout = getattr(config, "request_timeout_s", None)
    if timeout is None:
        return stall_s
    sends = 1 + int(getattr(config, "resends", 0))
    connects = 1 + int(getattr(config, "connect_retries", 0))
    reconnecting = connects * (
        float(getattr(config, "connect_timeout_s", 0)) + float(getattr(config, "max_backoff_s", 0))
    )
    return max(stall_s, sends * (float(timeout) + reconnecting) + 60.0)


class StallWatch:
    """When each busy worker was last heard from, and which have been silent too long."""

    def __init__(self, stall_s: float, call_s: float):
        self.stall_s, self.call_s = stall_s, call_s
        self._heard: dict[int, float] = {}

    def heard(self, slot: Any) -> None:
        """``slot``'s worker made progress: it sent something, or was sent its episode or an answer."""
        self._heard[slot.index] = time.monotonic()

    def timeout(self, busy: Iterable[Any], waiting: set[int], oldest_call_s: float) -> float:
        """Seconds until the next bound could pass (what ``wait()`` may block for)."""
        now = time.monotonic()
        left = [self.call_s - oldest_call_s] if oldest_call_s else []
        left += [self._heard.get(s.index, now) + self.stall_s - now for s in busy if s.index not in waiting]
        return max(0.0, min(left, default=self.stall_s))

    def stalled(self, busy: Iterable[Any], waiting: set[int]) -> list[Any]:
        """The busy slots not waiting for the policy whose workers have been silent for ``stall_s``."""
        now = time.monotonic()
        return [s for s in busy if s.index not in waiting and now - self._heard.get(s.index, now) > self.stall_s]
