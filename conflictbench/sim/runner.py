"""Playing a plan: a pool of simulator workers driven by the policy in this process.

The policy is loaded once, whatever the number of workers. One with ``act_batch`` serves every
worker's episodes at once (it keys per-episode state by ``observation.stream``). One without is
served one episode at a time: ``reset`` right before that episode's first ``act``, its queries
answered until it ends, while the other workers reset their next episodes and wait with their
first observation.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import wait
from typing import Any

from conflictbench.core import (
    INFRASTRUCTURE_ERROR_PREFIX,
    EpisodeRecord,
    PolicySpec,
    PolicyTraits,
    ServerUnavailable,
    SimulatorUnavailable,
    StoreFull,
    UserError,
)
from conflictbench.core.plugins import Plugins
from conflictbench.store.episodes import ClaimKeeper, EpisodeStore

from . import BACKENDS
from .backends import make_pool, probe_stack, release_probe
from .deciding import PolicyCalls, load_policy, reply_for, reset_error, start_policy
from .episode_rows import episode_record, make_items, seconds_each
from .libero_env import EnvSettings
from .messages import Abort, Done, EpisodeOutcome, Play, Query
from .plan import EpisodeSpec
from .planning import RunResult, left_to_play, run_identity
from .pool import WorkerPool
from .progress import plan_line, run_progress
from .slots import EpisodeQueue, Item, Slot
from .watchdog import PolicyStalled, StallWatch, call_bound, stall_bound


@dataclasses.dataclass
class _Backlog:
    """The episodes left to a run's loop: queued, deferred (another job holds their claims), and the stored
    ones as last read."""

    queue: EpisodeQueue
    stored: set[str]
    deferred: list[Item] = dataclasses.field(default_factory=list)


class Runner:
    """Plays episodes for one policy and writes each finished one to the store."""

    def __init__(
        self,
        plugins: Plugins,
        spec: PolicySpec,
        config: Any,
        *,
        store: EpisodeStore,
        workers: int = 1,
        seed: int = 7,
        progress: bool = True,
        on_episode: Callable[[EpisodeRecord], None] | None = None,
        backend: str = "local",
        ray_address: str | None = None,
        retry: bool = False,
        stall_timeout_s: float | None = None,
        max_steps: int | None = None,
    ):
        if workers < 1:
            raise UserError(f"run.workers must be >= 1, got {workers}")
        if backend not in BACKENDS:
            raise UserError(f"unknown run.backend {backend!r}; valid choices: {', '.join(BACKENDS)}")
        self.backend, self.ray_address, self.retry = backend, ray_address, retry
        self.stall_timeout_s = stall_timeout_s
        """How long a worker may be silent (``None``: derived from the step budget, ``watchdog.stall_bound``)."""
        self.max_steps = max_steps
        """A cap on every suite's step budget (``run.max_steps``; ``None``: the policy's own)."""
        self.plugins, self.spec, self.config = plugins, spec, config
        self.store, self.workers, self.seed = store, workers, seed
        self.config_hash = ""
        self.sampling_hash = ""
        self.code_versions: tuple[str, ...] = ()
        self.model_stack: tuple[str, ...] = ()
        self.policy_identity = ""
        self.progress, self.on_episode = progress, on_episode
        self._bar: Any = run_progress(0, spec.name, enabled=False)
        self._pool: WorkerPool | None = None
        self._policy: Any = None
        self._calls: PolicyCalls | None = None
        self._serving: Slot | None = None
        """The slot whose episode a policy without act_batch is serving (it serves one at a time)."""
        self._held: list[tuple[Slot, Any]] = []
        """First queries of episodes waiting their turn with such a policy, oldest first."""
        self._claims = ClaimKeeper(store)  # each run starts its own (a keeper's thread starts once)

    # -- planning --------------------------------------------------------------------------
    def jobs(self, plan: list[EpisodeSpec], traits: PolicyTraits) -> list[Item]:
        """Each planned episode with its worker's job (its identity, prompt text and step budget)."""
        return make_items(plan, traits, self.plugins, self.spec.name, self.config_hash, self.seed, self.sampling_hash)

    # -- the loop --------------------------------------------------------------------------
    def run(self, plan: list[EpisodeSpec]) -> RunResult:
        policy = load_policy(self.spec, self.config)
        try:
            return self._run_with(policy, plan)
        finally:  # also when nothing was left to play: a policy may hold a server process
            close = getattr(policy, "close", None)
            if callable(close):
                close()
            release_probe(self.backend)  # Ray: the probe's connection, where no pool took it over

    def _run_with(self, policy: Any, plan: list[EpisodeSpec]) -> RunResult:
        traits = PolicyTraits(policy)
        if self.max_steps is not None:  # a shorter budget is other episodes: the traits enter the identity
            traits.max_steps = {suite: min(steps, self.max_steps) for suite, steps in traits.max_steps.items()}
        settings = EnvSettings(needs_images=traits.needs_images, image_size=traits.image_size)
        identity = run_identity(
            self.plugins, self.spec.name, self.config, traits, probe_stack(settings, self.backend, self.ray_address)
        )
        self.config_hash, self.sampling_hash = identity.config_hash, identity.sampling_hash
        self.code_versions, self.model_stack = identity.code_versions, identity.model_stack
        self.policy_identity = identity.policy_identity
        missing = sorted({s.suite for s in plan} - set(traits.max_steps))
        if missing:
            raise UserError(f"policy {self.spec.name!r} declares no max_steps for {', '.join(missing)}")
        self.store.clean_stale_temporaries()
        items = self.jobs(plan, traits)
        todo, result = left_to_play(self.store, items, identity, self.spec.name, self.config, self.retry)
        if self.progress:
            stored = {i.job.episode_id for i in items} - {i.job.episode_id for i in todo}
            seconds, basis = seconds_each(self.store, items, stored, self.spec.name, self.config_hash)
            print(plan_line(len(todo), result.already_stored, seconds, self.workers, basis), file=sys.stderr)
        if not todo:
            return result

        # The pool first (Ray: connecting to the cluster), so a wrong address costs no model server's start.
        pool = self._pool = make_pool(settings, min(self.workers, len(todo)), self.backend, self.ray_address)
        pool.versions = dict(identity.stack)  # a worker on another stack than the probe's stops the run
        try:
            start_policy(self.spec, policy)  # only now that there is something to play
        except BaseException:
            pool.stop()
            raise
        self._policy, self._serving, self._held = policy, None, []
        self._calls = PolicyCalls(policy, traits)
        stall_s = self.stall_timeout_s or stall_bound(i.job.max_steps for i in todo)
        self._watch = StallWatch(stall_s, call_bound(self.config, stall_s))
        self._bar = run_progress(len(todo), self.spec.name, enabled=self.progress)
        self._claims = ClaimKeeper(self.store)
        try:
            with self._claims:  # renews the claims of the episodes being played, from a thread
                pool.start_all()
                self._loop(EpisodeQueue(todo), result, traits)
        except (ServerUnavailable, PolicyStalled):
            self._end_in_flight(result)
            raise
        except StoreFull as exc:  # nothing more can be stored: the episodes in flight are played by the next run
            raise exc.after(result.played) from None
        finally:
            for slot in pool.slots:
                if slot.item is not None:
                    self._release(slot.item.job.episode_id)
            self._calls.close()
            pool.stop()
            self._bar.close()
        return result

    def _next_item(
        self, slot: Slot, queue: EpisodeQueue, deferred: list[Item], stored: set[str], busy: set, result: RunResult
    ) -> Item | None:
        """The next episode this slot can claim (see EpisodeQueue.pop_for for the order)."""
        while (item := queue.pop_for(slot.task_key, busy)) is not None:
            eid = item.job.episode_id
            if eid in stored:
                continue
            if not self.store.claim(eid):
                deferred.append(item)  # another job is playing it right now
                continue
            self._claims.hold(eid)
            # `stored` is a snapshot: another job may have finished this episode (written, then
            # released its claim) since. Writes come before releases, so this check is enough.
            if self.store.path_for(self.spec.name, eid).exists():
                self._release(eid)
                result.played_elsewhere += 1
                self._bar.update(1)
                continue
            return item
        return None

    def _assign(self, slot: Slot, item: Item, result: RunResult, traits: PolicyTraits) -> None:
        job = dataclasses.replace(item.job, stream=slot.index)
        item = dataclasses.replace(item, job=job)
        slot.item, slot.task_key, slot.started = item, item.spec.task_key, time.time()
        if traits.batched:  # otherwise reset comes right before the episode's first act (_serve)
            try:
                self._policy.reset(job.instruction)
            except ServerUnavailable:
                raise
            except Exception as exc:
                self._finish(slot, EpisodeOutcome.failed(*reset_error(exc), len(job.targets)), result)
                return
        try:
            slot.conn.send(Play(job))
        except OSError:  # its worker has just gone: the next wait() finds it and plays the episode again
            pass
        self._watch.heard(slot)

    def _queried(self, slot: Slot, observation: Any, waiting: list[tuple[Slot, Any]], traits: PolicyTraits) -> None:
        """A worker asks for actions: decide now, or hold its episode until the policy is free."""
        if traits.batched or slot is self._serving:
            waiting.append((slot, observation))
        else:
            self._held.append((slot, observation))

    def _serve_next(self, waiting: list[tuple[Slot, Any]]) -> None:
        """Give a policy without act_batch the oldest held episode once it has finished its last one."""
        while self._serving is None and self._held:
            slot, observation = self._held.pop(0)
            try:
                self._policy.reset(slot.item.job.instruction)
            except ServerUnavailable:
                raise
            except Exception as exc:
                with contextlib.suppress(OSError):  # a gone worker is found by the next wait()
                    slot.conn.send(Abort(*reset_error(exc)))
                continue
            self._serving = slot
            waiting.append((slot, observation))

    def _loop(self, queue: EpisodeQueue, result: RunResult, traits: PolicyTraits) -> None:
        backlog = _Backlog(queue, self.store.stored_ids())
        self._fill(backlog, result, traits)
        while True:
            slots = [s for s in self._pool.slots if not s.retired]
            if not slots:
                raise SimulatorUnavailable(
                    "every simulator worker was lost; the episodes not yet played are played by the next run"
                )
            busy = [s for s in slots if s.item is not None]
            if busy:
                self._play_round(busy, queue, result, traits)
            elif backlog.deferred:
                self._await_other_jobs(backlog, result)
            else:
                return
            self._fill(backlog, result, traits)

    def _fill(self, backlog: _Backlog, result: RunResult, traits: PolicyTraits) -> None:
        """Give every idle worker an episode, while there are episodes it can claim."""
        for slot in self._pool.slots:
            while slot.item is None and not slot.retired:
                busy = {s.task_key for s in self._pool.slots if s.item is not None}
                item = self._next_item(slot, backlog.queue, backlog.deferred, backlog.stored, busy, result)
                if item is None:
                    break
                self._assign(slot, item, result, traits)

    def _await_other_jobs(self, backlog: _Backlog, result: RunResult) -> None:
        """Episodes another job is playing: wait for them to land, or take them over."""
        self._bar.set_postfix(waiting_for_other_jobs=len(backlog.deferred))
        time.sleep(1.0)
        backlog.stored = stored = self.store.stored_ids()
        for item in list(backlog.deferred):
            if item.job.episode_id in stored:
                backlog.deferred.remove(item)
                result.played_elsewhere += 1
                self._bar.update(1)
            elif not self.store.held_by_others([item.job.episode_id]):
                backlog.deferred.remove(item)
                backlog.queue.push(item)

    def _play_round(self, busy: list[Slot], queue: EpisodeQueue, result: RunResult, traits: PolicyTraits) -> None:
        """One round of the busy workers: read what they sent, ask the policy, send back what it decided."""
        waiting: list[tuple[Slot, Any]] = []
        answers = self._receive(busy, waiting, queue, result, traits)
        self._serve_next(waiting)
        if waiting:
            self._calls.submit(waiting)
        for slot, item, obs, raw in answers:
            if slot.item is not item:  # its worker died meanwhile; the slot plays another episode now
                continue
            try:
                slot.conn.send(reply_for(self.plugins, self.spec.name, item, obs, raw))
            except OSError:  # BrokenPipe, reset, a send timeout: the worker is gone; the next wait() finds it
                pass
            self._watch.heard(slot)
        self._check_stalls(result)

    def _receive(self, busy: list, waiting: list, queue: EpisodeQueue, result: RunResult, traits: PolicyTraits):
        """Wait for the busy workers' messages (or the policy's finished calls, returned) and act on each."""
        answers = []
        wakeup = self._calls.wakeup
        owners = {s.conn: s for s in busy} | {s.process.sentinel: s for s in busy}
        lost_now: set[int] = set()  # their waitables this round were the lost worker's, not its successor's
        patience = self._watch.timeout(busy, self._waiting_slots(), self._calls.oldest_call_s())
        for ready in wait([*owners, *wakeup], timeout=patience):
            if ready in wakeup:  # concurrent policy calls have finished (sentinels are ints too)
                answers += self._calls.collect()
                continue
            slot = owners.get(ready)
            if slot is None or slot.index in lost_now or slot.item is None or any(w[0] is slot for w in waiting):
                continue
            try:
                if ready == slot.process.sentinel and not slot.conn.poll():
                    raise EOFError
                msg = slot.conn.recv()
            except (EOFError, OSError):  # closed, reset, or stalled mid-message past the socket's timeout
                lost_now.add(slot.index)
                self._worker_lost(slot, queue, result)
                continue
            self._watch.heard(slot)
            match msg:
                case Query(observation=observation):
                    self._queried(slot, observation, waiting, traits)
                case Done(outcome=outcome):
                    self._finish(slot, outcome, result)
                case _:
                    raise TypeError(f"a worker sent {type(msg).__name__} during an episode")
        return answers

    def _waiting_slots(self) -> set[int]:
        """The slots whose episodes wait for the policy (their workers are silent by right)."""
        return self._calls.waiting_slots() | {slot.index for slot, _ in self._held}

    def _check_stalls(self, result: RunResult) -> None:
        """A policy call past its bound stops the run; a worker silent past its bound is replaced (watchdog.py)."""
        if (running := self._calls.oldest_call_s()) > self._watch.call_s:
            raise PolicyStalled(
                f"a call of policy {self.spec.name!r} has not returned in {running:.0f} s (limit "
                f"{self._watch.call_s:.0f} s, run.stall_timeout_s); every finished episode is stored, and the same "
                "command resumes the run"
            )
        busy = [s for s in self._pool.slots if s.item is not None and not s.retired]
        for slot in self._watch.stalled(busy, self._waiting_slots()):
            silent = f"the simulator worker sent nothing for {self._watch.stall_s:.0f} s; it was stopped and replaced"
            print(f"conflictbench: {silent} (episode {slot.item.job.episode_id} is played again by the next run)",
                  file=sys.stderr)  # fmt: skip
            self._pool.stop_worker(slot)
            error = f"{INFRASTRUCTURE_ERROR_PREFIX}: {silent}"
            self._finish(slot, EpisodeOutcome.failed(error, "simulator", len(slot.item.job.targets)), result)
            self._pool.restart(slot)

    def _worker_lost(self, slot: Slot, queue: EpisodeQueue, result: RunResult) -> None:
        """The worker playing ``slot``'s episode is gone (crashed, its node lost): the episode is played again
        by another worker, once; lost a second time it is stored as a ``simulator`` failure (left out of the
        measures, played again by the next run). Then the slot gets a new worker, or is retired."""
        item = slot.item
        reason = self._pool.lost_reason(slot)
        if item.losses == 0:
            self._free(slot)
            self._release(item.job.episode_id)
            queue.push(dataclasses.replace(item, losses=1))
            result.replayed_after_loss += 1
            print(f"conflictbench: {reason}; its episode is played again", file=sys.stderr)
        else:
            error = f"{INFRASTRUCTURE_ERROR_PREFIX}: {reason}"
            self._finish(slot, EpisodeOutcome.failed(error, "simulator", len(item.job.targets)), result)
        self._pool.restart(slot)

    def _release(self, episode_id: str) -> None:
        self.store.release(episode_id)
        self._claims.drop(episode_id)

    def _end_in_flight(self, result: RunResult) -> None:
        """The policy server is gone: store the episodes whose workers already sent their end, then stop
        the workers mid-episode (those episodes are not stored; their claims are released by ``run``)."""
        for slot in self._pool.slots:
            try:
                while slot.item is not None and slot.conn.poll():
                    msg = slot.conn.recv()
                    if isinstance(msg, Done):
                        self._finish(slot, msg.outcome, result)
            except (EOFError, OSError):
                pass
            if slot.process is not None:
                slot.process.kill()  # its episode cannot finish: no need to wait for it to reach a Stop

    def _free(self, slot: Slot) -> None:
        slot.item = None
        if self._serving is slot:
            self._serving = None
        self._held = [(s, o) for s, o in self._held if s is not slot]

    def _finish(self, slot: Slot, outcome: EpisodeOutcome, result: RunResult) -> None:
        item = slot.item
        assert item is not None
        record = episode_record(
            item,
            outcome,
            spec=self.spec,
            config=self.config,
            config_hash=self.config_hash,
            code_versions=self.code_versions,
            model_stack=self.model_stack,
            policy_identity=self.policy_identity,
            simulator=self._pool.versions,
            wall_time_s=time.time() - slot.started,
        )
        if item.job.episode_id in self._claims.lost:  # taken over while this job looked dead: the other one stores it
            self._claims.drop(item.job.episode_id)
            result.played_elsewhere += 1
        else:
            self.store.write(record)
            self._release(item.job.episode_id)
            result.played += 1
            result.succeeded += int(record.success)
            result.errors += int(record.error is not None)
        self._free(slot)
        self._bar.update(1)
        self._bar.set_postfix(success=result.succeeded, errors=result.errors)
        if self.on_episode is not None and item.job.episode_id not in self._claims.lost:
            self.on_episode(record)
