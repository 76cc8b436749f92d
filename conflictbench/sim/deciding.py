"""Asking the policy: one decision for the workers that wait, and the reply each of them gets.

Failures are sorted here, by where they were raised (``ERROR_KINDS``). A policy that raises, or
answers NaN, inf or the wrong shape, ends its episode as a failed one (``policy``: the model's
behaviour). An :class:`InfrastructureError` (its server answered an error: ``server``; the client's
own encode or decode failed, a :class:`ClientError`: ``client``) and a post-processor that raises or
returns a bad action (``plugin``) end the episode for a replay, left out of the measures. A
:class:`ServerUnavailable` is not caught: the run stops.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np

from conflictbench.core import (
    INFRASTRUCTURE_ERROR_PREFIX,
    ActionContext,
    InfrastructureError,
    PolicyError,
    PolicySpec,
    PolicyTraits,
    ServerUnavailable,
    UserError,
    as_action_chunk,
)
from conflictbench.core.plugins import Plugins
from conflictbench.core.policy import batch_outputs

from .messages import Abort, Actions
from .slots import Item


def load_policy(spec: PolicySpec, config: Any) -> Any:
    """The run's policy, loaded once, checked to have what the contract asks."""
    policy = _set_up(spec, "load", spec.load, config)
    for method in ("reset", "act"):
        if not callable(getattr(policy, method, None)):
            raise UserError(f"policy {spec.name!r} has no {method}() method")
    return policy


def start_policy(spec: PolicySpec, policy: Any) -> None:
    """Its optional ``start()``: called once there are episodes to play (a model server loads for minutes)."""
    start = getattr(policy, "start", None)
    if callable(start):
        _set_up(spec, "start", start)


def _set_up(spec: PolicySpec, what: str, function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)``; a failure that is not already a user error or a missing server becomes one line naming
    the policy (its loading or starting is set-up, not the model's behaviour)."""
    try:
        return function(*args)
    except (UserError, ServerUnavailable):
        raise
    except Exception as exc:
        raise UserError(f"could not {what} policy {spec.name!r}: {type(exc).__name__}: {exc}") from exc


def ask_policy(policy: Any, observations: list[Any], batched: bool) -> list[Any]:
    """The policy's answer to each observation: its raw output, or the error that ends that episode."""
    if batched:
        try:
            return batch_outputs(policy, observations)
        except ServerUnavailable:
            raise
        except Exception as exc:
            return [as_error(exc)] * len(observations)
    outputs: list[Any] = []
    for observation in observations:
        try:
            outputs.append(policy.act(observation))
        except ServerUnavailable:
            raise
        except Exception as exc:
            outputs.append(as_error(exc))
    return outputs


def reply_for(plugins: Plugins, policy: str, item: Item, observation: Any, raw: Any) -> Abort | Actions:
    """What the worker playing ``item`` gets: the chunk to execute (raw and post-processed), or why it stops."""
    if isinstance(raw, InfrastructureError):  # not the model's behaviour: stored apart, replayed next run
        return Abort(f"{INFRASTRUCTURE_ERROR_PREFIX}: {raw}", kind=raw.kind)
    try:
        if isinstance(raw, Exception):  # act_batch may end one episode alone by returning its error
            raise as_error(raw)
        chunk = as_action_chunk(raw)
    except PolicyError as exc:
        return Abort(str(exc))
    try:  # from here on, plugins' code: what fails is not the model's answer
        job = item.job
        executed = np.stack(
            [
                plugins.postprocess_action(
                    action.copy(),
                    ActionContext(
                        policy=policy,
                        suite=job.suite,
                        task_id=job.task_id,
                        prompt=item.spec.prompt,
                        case_id=item.spec.case_id,
                        step=observation.step + i,
                        chunk_index=i,
                    ),
                )
                for i, action in enumerate(chunk)
            ]
        )
        if not np.all(np.isfinite(executed)):
            raise PolicyError("post-processing produced a non-finite action")
    except PolicyError as exc:
        return Abort(str(exc), kind="plugin")
    except Exception as exc:
        return Abort(f"action post-processing raised {type(exc).__name__}: {exc}", kind="plugin")
    return Actions(raw=chunk, executed=executed)


def reset_error(exc: Exception) -> tuple[str, str]:
    """The ``error`` and ``error_kind`` of an episode whose policy ``reset`` raised."""
    if isinstance(exc, InfrastructureError):
        return f"{INFRASTRUCTURE_ERROR_PREFIX}: {exc}", exc.kind
    return f"policy reset raised {type(exc).__name__}: {exc}", "policy"


def as_error(exc: Exception) -> PolicyError | InfrastructureError:
    if isinstance(exc, (PolicyError, InfrastructureError)):
        return exc
    return PolicyError(f"policy raised {type(exc).__name__}: {exc}")


Answer = tuple[Any, Any, Any, Any]
"""(slot, the item it was playing when it asked, observation, the policy's raw output or error)."""


class PolicyCalls:
    """Answers the workers' queries from threads of their own, never the runner's: the runner keeps serving the
    workers and its watchdog (``watchdog.py``) keeps time while a call runs, and a call that never returns cannot
    stall the run unseen. A policy that declares ``concurrent_requests`` (a served one) gets each query as soon as
    it arrives, so N workers keep N requests in flight; any other is called once at a time, in one thread, with
    the queries that arrived meanwhile batched into its next call (as if it had been called from the runner).

    A finished call wakes the runner's ``wait()`` through a pipe (:attr:`wakeup`)."""

    def __init__(self, policy: Any, traits: PolicyTraits):
        self.policy, self.batched, self.concurrent = policy, traits.batched, traits.concurrent
        self._pending: dict[Future, tuple[list[tuple[Any, Any, Any]], float]] = {}
        """A call -> ((slot, item, observation) of each query it answers, when it started: monotonic)."""
        self._backlog: list[tuple[Any, Any]] = []  # queries waiting for a one-at-a-time policy's next call
        self._open = True
        self._read, self._write = os.pipe()
        os.set_blocking(self._read, False)
        self._pipe_lock = threading.Lock()  # a call finishing after close() must not write to a reused fd

    @property
    def wakeup(self) -> list[int]:
        """What ``wait()`` should watch besides the workers: the pipe, while calls are pending."""
        return [self._read] if self._pending else []

    def waiting_slots(self) -> set[int]:
        """The slots whose episodes wait for an answer (in a call, or for the next one)."""
        return {slot.index for queries, _ in self._pending.values() for slot, _, _ in queries} | {
            slot.index for slot, _ in self._backlog
        }

    def oldest_call_s(self) -> float:
        """How long the longest-running call has been running (0 without one)."""
        now = time.monotonic()
        return max((now - started for _, started in self._pending.values()), default=0.0)

    def submit(self, waiting: list[tuple[Any, Any]]) -> None:
        """Ask for these queries; their answers come through :meth:`collect`."""
        if self.concurrent:
            for slot, obs in waiting:
                self._call([(slot, obs)], batched=True)
        else:
            self._backlog += waiting
            if not self._pending:
                self._next_call()

    def _next_call(self) -> None:
        if self._backlog:
            queries, self._backlog = self._backlog, []
            self._call(queries, batched=self.batched)

    def _call(self, queries: list[tuple[Any, Any]], batched: bool) -> None:
        """One call in a daemon thread of its own: a call that never returns must not keep the process alive
        after the run has stopped (a pool's threads are joined at exit)."""
        future: Future = Future()
        observations = [obs for _, obs in queries]

        def call() -> None:
            try:
                future.set_result(ask_policy(self.policy, observations, batched))
            except BaseException as exc:  # ServerUnavailable: collect() raises it in the runner's thread
                future.set_exception(exc)

        self._pending[future] = ([(slot, slot.item, obs) for slot, obs in queries], time.monotonic())
        future.add_done_callback(self._wake)
        threading.Thread(target=call, name="conflictbench-policy", daemon=True).start()

    def _wake(self, _: Future) -> None:
        with self._pipe_lock:
            if self._open:  # else closed: the run has ended and a call outlived it
                os.write(self._write, b".")

    def collect(self) -> list[Answer]:
        """The answers of the calls that have finished (raises ServerUnavailable: the run stops)."""
        try:
            while os.read(self._read, 4096):
                pass
        except BlockingIOError:
            pass
        answers = []
        for future in [f for f in self._pending if f.done()]:
            queries, _ = self._pending.pop(future)
            answers += [(slot, item, obs, raw) for (slot, item, obs), raw in zip(queries, future.result(), strict=True)]
        if not self.concurrent and not self._pending:
            self._next_call()
        return answers

    def close(self) -> None:
        with self._pipe_lock:
            if self._open:
                os.close(self._read)
                os.close(self._write)
                self._open = False
