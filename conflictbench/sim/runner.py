"""Playing a plan: a pool of simulator workers driven by the policy in this process."""

from __future__ import annotations

import dataclasses
import datetime as _dt
import hashlib
import json
import multiprocessing as mp
import time
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import wait
from typing import Any, Callable

import numpy as np

from conflictbench.core import (
    ActionContext,
    EpisodeRecord,
    PolicyError,
    PolicySpec,
    PolicyTraits,
    SimulatorUnavailable,
    UserError,
    as_action_chunk,
)
from conflictbench.core.plugins import Plugins
from conflictbench.core.policy import batch_outputs
from conflictbench.store.episodes import EpisodeStore
from conflictbench.tasks.libero_tasks import base_task

from .libero_env import EnvSettings
from .plan import EpisodeSpec, episode_id
from .worker import EpisodeJob, worker_main

START_TIMEOUT_S = 300


@dataclass
class RunResult:
    planned: int = 0
    already_stored: int = 0
    played_elsewhere: int = 0
    """Episodes another job sharing the store was playing when this one reached them."""
    played: int = 0
    succeeded: int = 0
    errors: int = 0
    episode_ids: list[str] = field(default_factory=list)


@dataclass
class _Item:
    spec: EpisodeSpec
    job: EpisodeJob


@dataclass
class _Stream:
    index: int
    process: Any = None
    conn: Any = None
    policy: Any = None
    item: _Item | None = None
    task_key: tuple[str, int] | None = None
    started: float = 0.0


class Runner:
    """Plays episodes for one policy and writes each finished one to the store."""

    def __init__(self, plugins: Plugins, spec: PolicySpec, config: Any, *,
                 store: EpisodeStore, workers: int = 1, seed: int = 7, progress: bool = True,
                 on_episode: Callable[[EpisodeRecord], None] | None = None):
        if workers < 1:
            raise UserError(f"run.workers must be >= 1, got {workers}")
        self.plugins, self.spec, self.config = plugins, spec, config
        self.store, self.workers, self.seed = store, workers, seed
        self.config_hash = ""
        self.progress, self.on_episode = progress, on_episode
        self._versions: dict[str, str] = {}
        self._bar: Any = _NoBar()
        self._ctx = mp.get_context("spawn")  # never fork a process that may hold GL or CUDA state

    # -- policy ----------------------------------------------------------------------------
    def _load_policy(self) -> Any:
        try:
            policy = self.spec.load(self.config)
        except UserError:
            raise
        except Exception as exc:
            raise UserError(f"could not load policy {self.spec.name!r}: {type(exc).__name__}: {exc}") from exc
        for method in ("reset", "act"):
            if not callable(getattr(policy, method, None)):
                raise UserError(f"policy {self.spec.name!r} has no {method}() method")
        return policy

    # -- planning --------------------------------------------------------------------------
    def jobs(self, plan: list[EpisodeSpec], traits: PolicyTraits) -> list[_Item]:
        items = []
        for spec in plan:
            task = base_task(spec.suite, spec.task_id)
            text = self.plugins.format_prompt(spec.instruction, spec.prompt, self.spec.name)
            eid = episode_id(policy=self.spec.name, config_hash=self.config_hash, spec=spec,
                             prompt_text=text, seed=self.seed)
            job = EpisodeJob(
                episode_id=eid, suite=spec.suite, task_id=spec.task_id, bddl_path=task.bddl_path,
                init_state=spec.init_state, seed=self.seed, instruction=text, goal=task.goal,
                targets=task.targets, warmup_steps=traits.warmup_steps,
                max_steps=traits.max_steps[spec.suite], needs_privileged=traits.needs_privileged,
                case=spec.case,
            )
            items.append(_Item(spec, job))
        return items

    # -- workers ---------------------------------------------------------------------------
    def _start_worker(self, stream: _Stream, settings: EnvSettings) -> None:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=worker_main, args=(child, settings), daemon=True,
                                 name=f"conflictbench-worker-{stream.index}")
        proc.start()
        child.close()
        stream.process, stream.conn, stream.item, stream.task_key = proc, parent, None, None

    def _await_ready(self, streams: list[_Stream]) -> None:
        for stream in streams:
            if not stream.conn.poll(START_TIMEOUT_S):
                raise SimulatorUnavailable(f"a simulator worker did not start within {START_TIMEOUT_S} s")
            try:
                kind, payload = stream.conn.recv()
            except EOFError:
                raise SimulatorUnavailable(f"a simulator worker died while starting (exit code {stream.process.exitcode})") from None
            if kind == "fatal":
                raise SimulatorUnavailable(payload)
            self._versions = payload

    @staticmethod
    def _stop(streams: list[_Stream]) -> None:
        for stream in streams:
            try:
                if stream.conn is not None:
                    stream.conn.send(("stop",))
            except (BrokenPipeError, OSError):
                pass
        for stream in streams:
            if stream.process is not None:
                stream.process.join(timeout=10)
                if stream.process.is_alive():
                    stream.process.kill()

    # -- the loop --------------------------------------------------------------------------
    def run(self, plan: list[EpisodeSpec]) -> RunResult:
        policy = self._load_policy()
        traits = PolicyTraits(policy)
        self.config_hash = config_hash(self.spec.name, self.config, traits)
        missing = sorted({s.suite for s in plan} - set(traits.max_steps))
        if missing:
            raise UserError(f"policy {self.spec.name!r} declares no max_steps for {', '.join(missing)}")
        self.store.clean_stale_temporaries()
        items = self.jobs(plan, traits)
        result = RunResult(planned=len(items), episode_ids=[i.job.episode_id for i in items])
        stored = self.store.stored_ids()
        todo = [i for i in items if i.job.episode_id not in stored]
        result.already_stored = len(items) - len(todo)
        if not todo:
            return result

        settings = EnvSettings(needs_images=traits.needs_images, image_size=traits.image_size)
        streams = [_Stream(index=i) for i in range(min(self.workers, len(todo)))]
        for stream in streams:
            stream.policy = policy if (traits.batched or stream.index == 0) else self._load_policy()
        bar = self._bar = _progress(len(todo), self.spec.name, enabled=self.progress)
        try:
            for stream in streams:
                self._start_worker(stream, settings)
            self._await_ready(streams)
            self._loop(streams, deque(todo), result, traits)
        finally:
            for stream in streams:
                if stream.item is not None:
                    self.store.release(stream.item.job.episode_id)
            self._stop(streams)
            bar.close()
            closed = set()
            for stream in streams:
                if id(stream.policy) not in closed and callable(getattr(stream.policy, "close", None)):
                    closed.add(id(stream.policy))
                    stream.policy.close()
        return result

    def _next_item(self, stream: _Stream, queue: deque, deferred: list[_Item], stored: set[str],
                   busy_tasks: set[tuple[str, int]]) -> _Item | None:
        """The next episode for this stream: its current base task first (its env is built), then a
        base task no other worker is on (so each env is built by as few workers as possible)."""
        while queue:
            pick = (next((i for i in queue if i.spec.task_key == stream.task_key), None)
                    or next((i for i in queue if i.spec.task_key not in busy_tasks), None)
                    or queue[0])
            queue.remove(pick)
            if pick.job.episode_id in stored:
                continue
            if self.store.claim(pick.job.episode_id):
                return pick
            deferred.append(pick)  # another job is playing it right now
        return None

    def _assign(self, stream: _Stream, item: _Item, result: RunResult) -> None:
        job = EpisodeJob(**{**item.job.__dict__, "stream": stream.index})
        item = _Item(item.spec, job)
        stream.item, stream.task_key, stream.started = item, item.spec.task_key, time.time()
        try:
            stream.policy.reset(job.instruction)
        except Exception as exc:
            self._finish(stream, {"error": f"policy reset raised {type(exc).__name__}: {exc}"}, result)
            return
        stream.conn.send(("episode", job))

    def _loop(self, streams: list[_Stream], queue: deque, result: RunResult, traits: PolicyTraits) -> None:
        bar = self._bar
        deferred: list[_Item] = []
        stored = self.store.stored_ids()
        settings = EnvSettings(needs_images=traits.needs_images, image_size=traits.image_size)

        def fill() -> None:
            for stream in streams:
                while stream.item is None:
                    busy_tasks = {s.task_key for s in streams if s.item is not None}
                    item = self._next_item(stream, queue, deferred, stored, busy_tasks)
                    if item is None:
                        break
                    self._assign(stream, item, result)

        fill()
        while True:
            busy = [s for s in streams if s.item is not None]
            if not busy:
                if not deferred:
                    return
                # Episodes another job is playing: wait for them to land, or take them over.
                time.sleep(1.0)
                stored = self.store.stored_ids()
                for item in list(deferred):
                    if item.job.episode_id in stored:
                        deferred.remove(item)
                        result.played_elsewhere += 1
                        bar.update(1)
                    elif not self.store.held_by_others([item.job.episode_id]):
                        deferred.remove(item)
                        queue.append(item)
                fill()
                continue
            waiting: list[tuple[_Stream, Any]] = []
            for conn in wait([s.conn for s in busy] + [s.process.sentinel for s in busy]):
                stream = next((s for s in busy if conn in (s.conn, s.process.sentinel)), None)
                if stream is None or stream.item is None or any(w[0] is stream for w in waiting):
                    continue
                try:
                    if conn is stream.process.sentinel and not stream.conn.poll():
                        raise EOFError
                    kind, payload = stream.conn.recv()
                except (EOFError, ConnectionResetError):
                    code = stream.process.exitcode
                    self._finish(stream, {"error": f"simulator worker died (exit code {code})"}, result)
                    self._start_worker(stream, settings)
                    self._await_ready([stream])
                    continue
                if kind == "obs":
                    waiting.append((stream, payload))
                elif kind == "done":
                    self._finish(stream, payload, result)
            if waiting:
                self._decide(waiting, traits)
            fill()

    def _decide(self, waiting: list[tuple[_Stream, Any]], traits: PolicyTraits) -> None:
        outputs: list[Any]
        if traits.batched:
            try:
                outputs = batch_outputs(waiting[0][0].policy, [obs for _, obs in waiting])
            except Exception as exc:
                outputs = [_as_error(exc)] * len(waiting)
        else:
            outputs = []
            for stream, obs in waiting:
                try:
                    outputs.append(stream.policy.act(obs))
                except Exception as exc:
                    outputs.append(_as_error(exc))
        for (stream, obs), raw in zip(waiting, outputs):
            try:
                if isinstance(raw, PolicyError):
                    raise raw
                chunk = as_action_chunk(raw)
                job = stream.item.job
                executed = np.stack([
                    self.plugins.postprocess_action(action.copy(), ActionContext(
                        policy=self.spec.name, suite=job.suite, task_id=job.task_id,
                        prompt=stream.item.spec.prompt, case_id=stream.item.spec.case_id,
                        step=obs.step + i, chunk_index=i))
                    for i, action in enumerate(chunk)])
                if not np.all(np.isfinite(executed)):
                    raise PolicyError("post-processing produced a non-finite action")
            except PolicyError as exc:
                stream.conn.send(("abort", str(exc)))
                continue
            except Exception as exc:
                stream.conn.send(("abort", f"action post-processing raised {type(exc).__name__}: {exc}"))
                continue
            stream.conn.send(("act", chunk, executed))

    def _finish(self, stream: _Stream, payload: dict, result: RunResult) -> None:
        item = stream.item
        assert item is not None
        spec, job = item.spec, item.job
        case = spec.case
        record = EpisodeRecord(
            policy=self.spec.name, suite=spec.suite, task_id=spec.task_id, init_state=spec.init_state,
            prompt=spec.prompt, instruction=spec.instruction, seed=job.seed,
            case_id=spec.case_id, family=case.family if case else None, level=case.level if case else None,
            episode_id=job.episode_id, base_instruction=spec.base_instruction, prompt_text=job.instruction,
            max_steps=job.max_steps, target_names=job.targets,
            target_pos=np.zeros((0, len(job.targets), 3)),
            conflictbench_version=_own_version(), plugin=self.spec.plugin, plugin_version=self.spec.plugin_version,
            config_hash=self.config_hash, created_at=_dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            wall_time_s=time.time() - stream.started, **self._versions,
        )
        for key, value in payload.items():
            if key != "wall_time_s":
                setattr(record, key, value)
        self.store.write(record)
        self.store.release(job.episode_id)
        result.played += 1
        result.succeeded += int(record.success)
        result.errors += int(record.error is not None)
        stream.item = None
        self._bar.update(1)
        self._bar.set_postfix(success=result.succeeded, errors=result.errors)
        if self.on_episode is not None:
            self.on_episode(record)


def config_hash(policy: str, config: Any, traits: PolicyTraits) -> str:
    """Identifies everything about the policy that can change a rollout (not the run's bookkeeping)."""
    settings = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else config
    blob = json.dumps({"policy": policy, "config": settings, "traits": traits.as_dict()}, sort_keys=True, default=repr)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def _as_error(exc: Exception) -> PolicyError:
    if isinstance(exc, PolicyError):
        return exc
    return PolicyError(f"policy raised {type(exc).__name__}: {exc}")


def _own_version() -> str:
    import conflictbench

    return conflictbench.__version__


class _NoBar:
    def update(self, n: int = 1) -> None: ...
    def set_postfix(self, **kw: Any) -> None: ...
    def close(self) -> None: ...


def _progress(total: int, name: str, enabled: bool):
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="episode", desc=f"{name}", dynamic_ncols=True)
