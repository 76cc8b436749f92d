"""Simulator workers as Ray actors (``run.backend=ray``): one run's episodes played on every node of a cluster.

The runner does not know the difference. Each actor is reached through a local pipe, like a worker
process: a bridge thread per actor forwards what the runner sends (Play, Actions, Abort, Stop) as one
actor call, whose answer is the worker's next message (Ready or Fatal, Query, Done). When an actor is
lost (its node went away, its process crashed) the bridge closes the pipe and the slot's sentinel
fires: the runner sees a dead worker and plays that episode again on another one. The driver alone
writes the store, so an episode whose actor was lost is never stored twice.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from typing import Any

from conflictbench.core import SimulatorUnavailable, UserError

from .libero_env import EnvSettings
from .messages import Stop
from .pool import STOP_TIMEOUT_S, Slot, WorkerPool
from .worker import worker_main

#: How long a restart waits for the cluster to show a free CPU (a crashed actor's takes a moment to
#: come back); past it the slot is retired: its node is gone and the run goes on with fewer workers.
FREE_CPU_WAIT_S = 10.0
INSTALL_HINT = "run.backend=ray needs Ray: pip install 'conflictbench[cluster]'"


def import_ray():
    try:
        import ray
    except ImportError:
        raise UserError(INSTALL_HINT) from None
    return ray


class _Inbox:
    """The worker loop's end of the conversation inside an actor."""

    def __init__(self) -> None:
        self.incoming: queue.Queue = queue.Queue()
        self.outgoing: queue.Queue = queue.Queue()

    def send(self, message: Any) -> None:
        self.outgoing.put(message)

    def recv(self) -> Any:
        return self.incoming.get()


class SimulatorActor:
    """One LIBERO env on a Ray node: :func:`worker_main` in a thread of its own, fed a message per call
    (the thread keeps the GL context on one thread for the env's whole life)."""

    def __init__(self, settings: EnvSettings):
        self._inbox = _Inbox()
        self._thread = threading.Thread(target=worker_main, args=(self._inbox, settings), daemon=True)
        self._thread.start()

    def where(self) -> tuple[str, str, int]:
        import ray

        return ray.get_runtime_context().get_node_id(), ray.util.get_node_ip_address(), os.getpid()

    def ready(self) -> Any:
        return self._next()

    def exchange(self, message: Any) -> Any:
        """Hand ``message`` to the worker; its next message (``None`` once it stopped)."""
        self._inbox.incoming.put(message)
        if isinstance(message, Stop):
            self._thread.join(timeout=STOP_TIMEOUT_S)
            return None
        return self._next()

    def _next(self) -> Any:
        while True:
            try:
                return self._inbox.outgoing.get(timeout=1.0)
            except queue.Empty:
                if not self._thread.is_alive() and self._inbox.outgoing.empty():
                    raise RuntimeError("the simulator worker's thread ended") from None


class ActorHandle:
    """What the runner knows of a worker process, for an actor: a sentinel that fires when it is gone,
    ``kill`` and ``join``; and where it runs."""

    def __init__(self, ray: Any, actor: Any):
        self._ray, self.actor = ray, actor
        self.sentinel, self._gone = os.pipe()  # readable (EOF) once the bridge has ended
        self.lost_because: str | None = None
        self.node_id, self.node_ip, self.pid = "?", "?", 0
        self.bridge: threading.Thread | None = None

    def kill(self) -> None:
        try:
            self._ray.kill(self.actor, no_restart=True)
        except Exception:  # already gone
            pass

    def is_alive(self) -> bool:
        return self.bridge is not None and self.bridge.is_alive()

    def join(self, timeout: float | None = None) -> None:
        if self.bridge is not None:
            self.bridge.join(timeout)

    def mark_gone(self) -> None:
        if self._gone is not None:
            os.close(self._gone)
            self._gone = None

    def close(self) -> None:
        self.mark_gone()
        if self.sentinel is not None:
            os.close(self.sentinel)
            self.sentinel = None


class RayWorkerPool(WorkerPool):
    """A :class:`WorkerPool` whose workers are Ray actors, one CPU each, spread over the cluster's nodes.

    ``address``: ``run.ray_address``; ``None`` uses ``RAY_ADDRESS``, or starts Ray on this machine."""

    def __init__(self, settings: EnvSettings, size: int, address: str | None = None):
        super().__init__(settings, size)
        ray = self._ray = import_ray()
        self._owns_ray = not ray.is_initialized()
        if self._owns_ray:
            try:
                ray.init(address=address, logging_level=logging.WARNING, include_dashboard=False)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                where = address or os.environ.get("RAY_ADDRESS") or "a new local instance"
                raise SimulatorUnavailable(f"cannot connect to Ray ({where}): {exc}") from None
        cpus = ray.cluster_resources().get("CPU", 0)
        if cpus < size:
            self.stop()
            raise UserError(f"run.workers={size} needs {size} CPUs in the Ray cluster; it has {cpus:g}")
        self._actor_class = ray.remote(num_cpus=1, max_restarts=0)(SimulatorActor)

    def start(self, slot: Slot) -> None:
        actor = self._actor_class.options(scheduling_strategy="SPREAD").remote(self.settings)
        handle = ActorHandle(self._ray, actor)
        parent, child = self._ctx.Pipe()
        handle.bridge = threading.Thread(
            target=self._bridge, args=(handle, child), daemon=True, name=f"conflictbench-ray-{slot.index}"
        )
        handle.bridge.start()
        slot.process, slot.conn, slot.item, slot.task_key = handle, parent, None, None

    def _bridge(self, handle: ActorHandle, end: Any) -> None:
        ray, actor = self._ray, handle.actor
        try:
            handle.node_id, handle.node_ip, handle.pid = ray.get(actor.where.remote())
            end.send(ray.get(actor.ready.remote()))
            while True:
                reply = ray.get(actor.exchange.remote(end.recv()))
                if reply is None:  # it stopped
                    return
                end.send(reply)
        except (EOFError, OSError):  # the runner closed its end
            pass
        except Exception as exc:  # RayActorError (node or process lost), RayTaskError (the worker thread ended)
            handle.lost_because = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        finally:
            end.close()
            handle.mark_gone()

    def lost_reason(self, slot: Slot) -> str:
        handle = slot.process
        return f"the Ray actor on node {handle.node_ip} was lost ({handle.lost_because or 'it ended'})"

    def restart(self, slot: Slot) -> None:
        """A new actor wherever a CPU is free; none within ``FREE_CPU_WAIT_S``: the slot is retired."""
        self._drop(slot)
        deadline = time.monotonic() + FREE_CPU_WAIT_S
        while self._ray.available_resources().get("CPU", 0) < 1:
            if time.monotonic() > deadline:
                slot.retired = True
                return
            time.sleep(0.5)
        super().restart(slot)

    def _drop(self, slot: Slot) -> None:
        if slot.process is not None:
            slot.process.kill()
            slot.process.join(STOP_TIMEOUT_S)
            slot.process.close()
        if slot.conn is not None:
            slot.conn.close()
        slot.process, slot.conn, slot.item = None, None, None

    def stop(self) -> None:
        super().stop()  # Stop through every bridge, then kill what is left
        for slot in self.slots:
            self._drop(slot)
        if self._owns_ray and self._ray.is_initialized():
            self._ray.shutdown()
