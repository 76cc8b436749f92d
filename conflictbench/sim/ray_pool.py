"""Simulator workers as Ray actors (``run.backend=ray``): one run's episodes played on every node of a cluster.

Ray places the actors (one CPU each, spread over the nodes) and tells when one is gone; the
conversation itself is the local pool's: each actor runs :func:`worker_main` over a connection to a
listener of this process (``multiprocessing.connection``, authenticated with a key made per run), so
an episode step costs what it costs locally plus the network's round trip. The runner does not know
the difference. An actor lost (its process crashed: the socket closes; its node went away: Ray says
so) is a dead worker to the runner, which plays that episode again on another one. The driver alone
writes the store, so an episode whose actor was lost is never stored twice.
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
import time
from multiprocessing.connection import Client, Listener
from typing import Any

from conflictbench.core import SimulatorUnavailable, UserError

from .libero_env import EnvSettings
from .pool import START_TIMEOUT_S, STOP_TIMEOUT_S, Slot, WorkerPool
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


class SimulatorActor:
    """One LIBERO env on a Ray node, talking to the driver over its own connection."""

    def serve(self, address: Any, authkey: bytes, token: str, settings: EnvSettings) -> None:
        """Connect, say who this is and where it runs, then be a worker until told to stop."""
        import ray

        conn = Client(address, authkey=authkey)
        try:
            conn.send((token, ray.get_runtime_context().get_node_id(), ray.util.get_node_ip_address(), os.getpid()))
            worker_main(conn, settings)
        finally:
            conn.close()


class ActorHandle:
    """What the runner knows of a worker process, for an actor: a sentinel that fires when it is gone,
    ``kill`` and ``join``; and where it runs."""

    def __init__(self, ray: Any, actor: Any, token: str):
        self._ray, self.actor, self.token = ray, actor, token
        self.sentinel, self._gone = os.pipe()  # readable (EOF) once the actor's serve call has ended
        self.lost_because: str | None = None
        self.node_id, self.node_ip, self.pid = "?", "?", 0
        self.conn: Any = None
        self.arrived = threading.Event()
        self.watcher: threading.Thread | None = None

    def watch(self, serving: Any) -> None:
        """Wait (in a thread) for the actor's serve call to end: returned (stopped) or failed (lost)."""
        try:
            self._ray.get(serving)
        except Exception as exc:  # RayActorError: its process or node is gone; RayTaskError: serve raised
            text = str(exc).strip()
            self.lost_because = f"{type(exc).__name__}: {text.splitlines()[0] if text else ''}"
        finally:
            os.close(self._gone)
            self._gone = None

    def kill(self) -> None:
        try:
            self._ray.kill(self.actor, no_restart=True)
        except Exception:  # already gone
            pass

    def is_alive(self) -> bool:
        return self.watcher is not None and self.watcher.is_alive()

    def join(self, timeout: float | None = None) -> None:
        if self.watcher is not None:
            self.watcher.join(timeout)

    def close(self) -> None:
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
        self._listener: Listener | None = None
        self._closing = False
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
        self._authkey = secrets.token_bytes(32)
        # On the address the cluster knows this node by: the actors on other nodes connect to it.
        self._listener = Listener((ray.util.get_node_ip_address(), 0), authkey=self._authkey)
        self._expected: dict[str, ActorHandle] = {}
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True, name="conflictbench-ray-listener").start()

    def _accept(self) -> None:
        """Hand each actor's connection to its slot (actors connect in any order: each says its token)."""
        while True:
            try:
                conn = self._listener.accept()
            except OSError:  # the listener was closed: the run is over
                return
            except Exception:  # a client without the key (AuthenticationError): ignore it
                continue
            if self._closing:  # the wake-up call of stop()
                conn.close()
                return
            try:
                token, node_id, node_ip, pid = conn.recv()
            except (EOFError, OSError, ValueError, TypeError):
                conn.close()
                continue
            with self._lock:
                handle = self._expected.pop(token, None)
            if handle is None:
                conn.close()
                continue
            handle.node_id, handle.node_ip, handle.pid, handle.conn = node_id, node_ip, pid, conn
            handle.arrived.set()

    def start(self, slot: Slot) -> None:
        token = secrets.token_hex(8)
        actor = self._actor_class.options(scheduling_strategy="SPREAD").remote()
        handle = ActorHandle(self._ray, actor, token)
        with self._lock:
            self._expected[token] = handle
        serving = actor.serve.remote(self._listener.address, self._authkey, token, self.settings)
        handle.watcher = threading.Thread(target=handle.watch, args=(serving,), daemon=True)
        handle.watcher.start()
        slot.process, slot.conn, slot.item, slot.task_key = handle, None, None, None

    def await_ready(self, slots: list[Slot]) -> None:
        """Wait for each actor to be placed and connect, then for its simulator import (as the local pool)."""
        deadline = time.monotonic() + START_TIMEOUT_S
        for slot in slots:
            handle = slot.process
            while not handle.arrived.wait(0.2):
                if not handle.is_alive():
                    raise SimulatorUnavailable(f"a simulator worker died while starting: {self.lost_reason(slot)}")
                if time.monotonic() > deadline:
                    raise SimulatorUnavailable(
                        f"a Ray simulator actor did not start within {START_TIMEOUT_S} s (no node can place it, "
                        "or its node cannot reach this one's address)"
                    )
            slot.conn = handle.conn
        super().await_ready(slots)

    def lost_reason(self, slot: Slot) -> str:
        handle = slot.process
        return f"the Ray actor on node {handle.node_ip} was lost ({handle.lost_because or 'its connection closed'})"

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
        super().stop()  # Stop to every actor, a common deadline, then kill what is left
        for slot in self.slots:
            self._drop(slot)
        if self._listener is not None:
            self._closing = True
            try:  # wake the accepting thread (closing a socket does not interrupt a blocked accept)
                Client(self._listener.address, authkey=self._authkey).close()
            except OSError:
                pass
            self._listener.close()
        if self._owns_ray and self._ray.is_initialized():
            self._ray.shutdown()
