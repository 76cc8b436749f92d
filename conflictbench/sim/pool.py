"""The local worker pool: simulator processes on this machine (what they play and wait in is :mod:`.slots`)."""

from __future__ import annotations

import multiprocessing as mp
import time

from conflictbench.core import SimulatorUnavailable

from .libero_env import EnvSettings
from .messages import Fatal, Ready, Stop
from .slots import Slot, sigint_ignored
from .worker import worker_main

START_TIMEOUT_S = 300
STOP_TIMEOUT_S = 10.0  # for all workers together to leave after Stop, before they are killed


class VersionMismatch(SimulatorUnavailable):
    """A worker's simulator is not the run's (another node's installation): the run stops."""


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
