"""The worker pool's parts: simulator processes and the queue of episodes waiting for them."""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import signal
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from conflictbench.core import SimulatorUnavailable

from .libero_env import EnvSettings
from .messages import EpisodeJob, Fatal, Ready, Stop
from .plan import EpisodeSpec
from .worker import worker_main

START_TIMEOUT_S = 300
STOP_TIMEOUT_S = 10.0  # for all workers together to leave after Stop, before they are killed
TaskKey = tuple[str, int]


class VersionMismatch(SimulatorUnavailable):
    """A worker's simulator is not the run's (another node's installation): the run stops."""


@dataclass
class Item:
    """A planned episode with everything its worker needs."""

    spec: EpisodeSpec
    job: EpisodeJob
    losses: int = 0
    """Times a worker was lost while playing it (it is played again once; see the runner)."""


@dataclass
class Slot:
    """One worker process and what it is doing (``stream`` in observations is its index)."""

    index: int
    process: Any = None
    conn: Any = None
    item: Item | None = None
    task_key: TaskKey | None = None
    started: float = 0.0
    retired: bool = False
    """Its worker was lost and none could take its place (a Ray node gone): it plays no more."""


class EpisodeQueue:
    """Episodes grouped by base task, so a worker can stay on the task whose env it has built."""

    def __init__(self, items: Iterable[Item] = ()):
        self._groups: OrderedDict[TaskKey, deque[Item]] = OrderedDict()
        for item in items:
            self.push(item)

    def push(self, item: Item) -> None:
        self._groups.setdefault(item.spec.task_key, deque()).append(item)

    def __bool__(self) -> bool:
        return bool(self._groups)

    def pop_for(self, current: TaskKey | None, busy: set[TaskKey]) -> Item | None:
        """The next episode: of ``current`` if any, else of a task no worker is busy with, else any."""
        if not self._groups:
            return None
        key = (
            current
            if current in self._groups
            else next((k for k in self._groups if k not in busy), next(iter(self._groups)))
        )
        group = self._groups[key]
        item = group.popleft()
        if not group:
            del self._groups[key]
        return item


@contextlib.contextmanager
def sigint_ignored():
    """SIGINT ignored while child processes start, so they inherit it ignored (a Ctrl-C in a terminal reaches
    the whole process group: workers still importing would each print a KeyboardInterrupt traceback)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:  # a handler not installed from Python reads as None: the default then
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)


class WorkerPool:
    """Starts, watches and stops the simulator processes (started with 'spawn': never fork GL/CUDA state)."""

    def __init__(self, settings: EnvSettings, size: int):
        self.settings = settings
        self.slots = [Slot(index=i) for i in range(size)]
        self.versions: dict[str, str] = {}
        self._ctx = mp.get_context("spawn")

    def start(self, slot: Slot) -> None:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(
            target=worker_main, args=(child, self.settings), daemon=True, name=f"conflictbench-worker-{slot.index}"
        )
        with sigint_ignored():  # the worker is born ignoring Ctrl-C: the main process stops it (no tracebacks)
            proc.start()
        child.close()
        slot.process, slot.conn, slot.item, slot.task_key = proc, parent, None, None

    def await_ready(self, slots: list[Slot]) -> None:
        """Wait for each worker's simulator import; a worker that cannot start stops the run."""
        for slot in slots:
            try:
                if not self.message_within(slot, START_TIMEOUT_S):
                    raise SimulatorUnavailable(f"a simulator worker did not start within {START_TIMEOUT_S} s")
                msg = slot.conn.recv()
            except (EOFError, OSError):
                lost = self.lost_reason(slot)
                raise SimulatorUnavailable(f"a simulator worker died while starting: {lost}") from None
            if isinstance(msg, Fatal):
                raise SimulatorUnavailable(msg.message)
            if not isinstance(msg, Ready):
                raise SimulatorUnavailable(f"a simulator worker said {type(msg).__name__} instead of Ready")
            self.check_versions(msg.versions)
            self.versions = dict(msg.versions)

    def message_within(self, slot: Slot, timeout: float) -> bool:
        """Whether ``slot``'s worker has said something (or hung up) within ``timeout`` seconds."""
        return slot.conn.poll(timeout)

    def check_versions(self, versions: dict[str, str]) -> None:
        """One run's episodes come from one simulator: a worker reporting other versions stops the run."""
        if self.versions and versions != self.versions:
            differ = sorted(k for k in set(versions) | set(self.versions) if versions.get(k) != self.versions.get(k))
            raise VersionMismatch(
                "simulator workers run different stacks ("
                + ", ".join(f"{k}: {self.versions.get(k)} vs {versions.get(k)}" for k in differ)
                + "); install the same simulator, GL stack and image libraries everywhere"
            )

    def lost_reason(self, slot: Slot) -> str:
        """Why ``slot``'s worker is gone, in words (stored as the error of an episode it could not finish)."""
        return f"the worker process died (exit code {slot.process.exitcode})"

    def start_all(self) -> None:
        for slot in self.slots:
            self.start(slot)
        self.await_ready(self.slots)

    def restart(self, slot: Slot) -> None:
        self.start(slot)
        self.await_ready([slot])

    def stop_worker(self, slot: Slot) -> None:
        """End ``slot``'s worker now, whatever it is doing (even stopped: SIGKILL reaches a SIGSTOPped process)."""
        if slot.process is not None:
            slot.process.kill()
            slot.process.join(STOP_TIMEOUT_S)

    def stop(self) -> None:
        for slot in self.slots:
            try:
                if slot.conn is not None:
                    slot.conn.send(Stop())
            except (BrokenPipeError, OSError):
                pass
        deadline = time.monotonic() + STOP_TIMEOUT_S  # one wait for all: a Ctrl-C never takes N times as long
        for slot in self.slots:
            if slot.process is not None:
                slot.process.join(timeout=max(0.0, deadline - time.monotonic()))
                if slot.process.is_alive():
                    slot.process.kill()


def make_pool(settings: EnvSettings, size: int, backend: str = "local", ray_address: str | None = None) -> WorkerPool:
    """A run's workers: processes here, or Ray actors on a cluster (``run.backend``)."""
    if backend == "ray":
        from .ray_pool import RayWorkerPool

        return RayWorkerPool(settings, size, address=ray_address)
    return WorkerPool(settings, size)
