"""Playing a stored episode again with a camera on: its executed actions, from its seed and initial state.

A policy that ran without cameras still gets a video this way. The replay is deterministic (a camera
env steps exactly as a camera-less one, see :func:`.libero_env.forward_like_a_render_context`), so its
end-effector path must equal the stored one; :attr:`ReplayResult.deviation_m` says by how much it does
not, and the viewer shows that on the page. Replays run in their own processes (the GL backend is chosen
per process), several at once, each keeping the env of the base task it played last.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from .libero_env import EnvSettings
from .slots import sigint_ignored

CAMERA = "agentview"


class FrameSink(Protocol):
    """Where the frames of one replay go (a video encoder); picklable, opened in the replay's process."""

    def open(self) -> None: ...
    def add(self, frame: np.ndarray) -> None: ...
    def close(self) -> int: ...  # bytes written
    def abort(self) -> None: ...  # after a failure: keep nothing


@dataclass(frozen=True)
class ReplayJob:
    """One stored episode to play again; ``eef_pos`` is its stored path (H+1 states) to check against."""

    episode_id: str
    suite: str
    task_id: int
    init_state: int
    seed: int
    warmup_steps: int
    actions: np.ndarray
    eef_pos: np.ndarray
    sink: Any  # a FrameSink
    frame_every: int = 1
    """A frame of every n-th state (and of the last): each render costs ~0.1 s on a CPU, a step 0.01 s."""
    control_mode: str = "relative"
    """How the arm read the actions after the warm-up, as the episode was played."""

    @classmethod
    def of(cls, record: Any, sink: Any, frame_every: int = 1) -> ReplayJob:
        """The job that plays a stored ``record`` (an :class:`~conflictbench.core.EpisodeRecord`) again as it was
        played: its warm-up and control mode, or, in a store written before those columns, the defaults of then."""
        from conflictbench.core.policy import DEFAULT_WARMUP_STEPS

        warmup = DEFAULT_WARMUP_STEPS if record.warmup_steps is None else record.warmup_steps
        return cls(record.episode_id, record.suite, record.task_id, record.init_state, record.seed, warmup,
                   record.actions, record.eef_pos, sink, frame_every, record.control_mode or "relative")  # fmt: skip

    def keeps(self, state: int) -> bool:
        return state % self.frame_every == 0 or state == len(self.actions)

    @property
    def task_key(self) -> tuple[str, int]:
        return self.suite, self.task_id


@dataclass(frozen=True)
class ReplayResult:
    episode_id: str
    steps: int
    deviation_m: float | None
    """Largest distance between the replayed and the stored end-effector position (None: nothing compared)."""
    bytes: int = 0
    seconds: float = 0.0
    error: str | None = None


# -- in a replay process ---------------------------------------------------------------------------------
_env_cache: dict[str, Any] = {}


def _start(image_size: int) -> None:
    from . import libero_env

    libero_env.configure_process(EnvSettings(needs_images=True, image_size=image_size))
    _env_cache["settings"] = EnvSettings(needs_images=True, image_size=image_size)


def _env_for(job: ReplayJob):
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states

    from . import libero_env

    if _env_cache.get("key") != job.task_key:
        if _env_cache.get("env") is not None:
            _env_cache["env"].close()
        _env_cache["env"] = libero_env.make_env(
            base_task(job.suite, job.task_id).bddl_path, _env_cache["settings"], cameras=(CAMERA,)
        )
        _env_cache["init_states"] = load_init_states(job.suite, job.task_id)
        _env_cache["key"] = job.task_key
    return _env_cache["env"], _env_cache["init_states"]


def replay(job: ReplayJob) -> ReplayResult:
    """Play ``job`` and hand each camera frame (upright, as people look at it) to its sink."""
    from . import libero_env
    from .worker import NOOP_ACTION, as_stepped, set_control_mode

    start = time.perf_counter()
    path: list[np.ndarray] = []
    try:
        env, init_states = _env_for(job)
        env.seed(job.seed)
        env.reset()
        gate = libero_env.CameraGate(env)  # render only the frames that go into the video
        gate.set(job.warmup_steps == 0)
        obs = env.set_init_state(init_states[job.init_state])
        for k in range(job.warmup_steps):
            gate.set(k == job.warmup_steps - 1)
            obs, _, _, _ = env.step(NOOP_ACTION)
        set_control_mode(env, job.control_mode)
        eef_site = env.env.robots[0].eef_site_id
        job.sink.open()
        for state in range(len(job.actions) + 1):  # state 0: after the warm-up; state i: after action i
            if state:
                gate.set(job.keeps(state))
                action = np.asarray(job.actions[state - 1], dtype=np.float64)
                obs, _, _, _ = env.step(as_stepped(action, job.control_mode))
            path.append(env.sim.data.site_xpos[eef_site].copy())
            if job.keeps(state):
                job.sink.add(np.ascontiguousarray(obs[f"{CAMERA}_image"][::-1, ::-1]))  # LIBERO renders upside down
        written = job.sink.close()
    except Exception as exc:  # a simulator or encoder failure is this replay's, not the run's
        _env_cache.pop("key", None)
        job.sink.abort()
        return failed(job, f"{type(exc).__name__}: {exc}", time.perf_counter() - start)
    deviation = path_deviation(np.array(path), job.eef_pos)
    return ReplayResult(job.episode_id, len(job.actions), deviation, written, time.perf_counter() - start)


def failed(job: ReplayJob, error: str, seconds: float = 0.0) -> ReplayResult:
    return ReplayResult(job.episode_id, 0, None, 0, seconds, error)


def path_deviation(replayed: np.ndarray, stored: np.ndarray) -> float:
    """Largest distance between two paths state by state (inf when their lengths differ)."""
    if replayed.shape != stored.shape:
        return float("inf")
    return float(np.max(np.linalg.norm(replayed - stored, axis=1))) if len(stored) else 0.0


# -- from the main process --------------------------------------------------------------------------------
def replay_all(
    jobs: Iterable[ReplayJob],
    *,
    workers: int = 2,
    image_size: int = 256,
) -> Iterator[ReplayResult]:
    """Replay ``jobs`` in ``workers`` processes, as they finish. ``jobs`` is read lazily (a few per process in
    flight), so it can load episodes as they are needed; give it grouped by base task (an env is built once per
    task and process). Leaving early (an error, Ctrl-C, the generator closed) ends the processes at once."""
    import multiprocessing as mp

    jobs = iter(jobs)
    running: dict[Any, ReplayJob] = {}
    executor: ProcessPoolExecutor | None = None
    finished = False

    def submit_more() -> None:
        while len(running) < 2 * workers and (job := next(jobs, None)) is not None:
            with sigint_ignored():  # a replay process is born (on a submit) ignoring Ctrl-C: we end it
                running[executor.submit(replay, job)] = job

    try:
        with sigint_ignored():
            executor = ProcessPoolExecutor(
                max_workers=max(1, workers), mp_context=mp.get_context("spawn"), initializer=_start,
                initargs=(image_size,),
            )  # fmt: skip
        submit_more()
        while running:
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                job = running.pop(future)
                try:
                    result = future.result()
                except Exception as exc:  # the replay process died (a crash in the GL stack, killed)
                    result = failed(job, f"the replay process ended: {type(exc).__name__}: {exc}")
                yield result
            submit_more()
        finished = True
    finally:
        if executor is not None:
            processes = [] if finished else list(getattr(executor, "_processes", {}).values())
            for process in processes:  # shutdown() alone would wait for the replays under way: end them now
                process.terminate()
            executor.shutdown(wait=finished, cancel_futures=True)
            for process in processes:
                process.join(timeout=5)
