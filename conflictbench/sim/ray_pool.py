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
import re
import secrets
import socket
import struct
import sys
import threading
import time
from multiprocessing.connection import Client, Connection, answer_challenge, deliver_challenge
from typing import Any

from conflictbench.core import SimulatorUnavailable, UserError

from .libero_env import EnvSettings
from .pool import STOP_TIMEOUT_S, VersionMismatch, WorkerPool
from .slots import Slot
from .stack import PROBE_TIMEOUT_S
from .worker import worker_main

#: How long a restart waits for the cluster to show a free CPU (a crashed actor's takes a moment to
#: come back); past it the slot is retired: its node is gone and the run goes on with fewer workers.
FREE_CPU_WAIT_S = 10.0
#: A connection must authenticate within this; once it has, a message stalled this long part-way is a lost
#: node (a frozen machine leaves its connection open: without it, the run would wait on it for ever).
HANDSHAKE_TIMEOUT_S = 10.0
MESSAGE_TIMEOUT_S = 60.0
INSTALL_HINT = "run.backend=ray needs Ray: pip install 'conflictbench[cluster]'"


def import_ray():
    try:
        import ray
    except ImportError:
        raise UserError(INSTALL_HINT) from None
    return ray


#: Ray was connected by the stack probe (``probe_on_cluster``): the pool that follows owns the connection.
_probe_connected = False


def probe_on_cluster(settings: EnvSettings, address: str | None) -> dict[str, str]:
    """``stack.stack_probe`` as a Ray task on the cluster (a node that plays episodes, not the driver's), connecting
    to Ray if nothing has yet; the connection is the run's pool's to keep (:func:`release_probe_connection`)."""
    global _probe_connected
    ray = import_ray()
    if not ray.is_initialized():
        connect(ray, address)
        _probe_connected = True
    task = ray.remote(num_cpus=1, max_retries=0)(_probe_task)
    try:
        said = ray.get(task.remote(settings), timeout=PROBE_TIMEOUT_S)
    except Exception as exc:  # a timeout, a lost task: Ray's own exception types
        release_probe_connection()
        raise SimulatorUnavailable(f"the simulator's stack probe on the Ray cluster failed: {type(exc).__name__}: "
                                   f"{exc}") from None  # fmt: skip
    if isinstance(said, str):
        release_probe_connection()
        raise SimulatorUnavailable(f"cannot start the simulator's stack on the Ray cluster: {said}")
    return said


def _probe_task(settings: EnvSettings) -> dict[str, str] | str:
    try:
        from . import libero_env
        from .stack import stack_probe

        libero_env.configure_process(settings)
        return stack_probe(settings.needs_images)
    except Exception as exc:  # said as text: the driver says it in one line
        return f"{type(exc).__name__}: {exc}"


def release_probe_connection() -> None:
    """Disconnect from Ray where the stack probe connected and no pool took the connection over."""
    global _probe_connected
    if _probe_connected:
        _probe_connected = False
        import_ray().shutdown()


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
        global _probe_connected
        ray = self._ray = import_ray()
        connected = ray.is_initialized()
        self._owns_ray = not connected or _probe_connected
        _probe_connected = False  # this pool keeps (and ends) the connection the stack probe made
        self._server: socket.socket | None = None
        self._closing = False
        if not connected:
            connect(ray, address)
        cpus = ray.cluster_resources().get("CPU", 0)
        if cpus < size:
            self.stop()
            raise UserError(f"run.workers={size} needs {size} CPUs in the Ray cluster; it has {cpus:g}")
        self._actor_class = ray.remote(num_cpus=1, max_restarts=0)(SimulatorActor)
        self._authkey = secrets.token_bytes(32)
        # On the address the cluster knows this node by: the actors on other nodes connect to it.
        self._server = socket.create_server((ray.util.get_node_ip_address(), 0))
        self._server.settimeout(0.5)  # the accepting thread looks at _closing this often
        self._address = self._server.getsockname()[:2]
        self._expected: dict[str, ActorHandle] = {}
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True, name="conflictbench-ray-listener").start()

    def _accept(self) -> None:
        """Take connections; each is authenticated in a thread of its own (a silent one blocks nobody)."""
        while not self._closing:
            try:
                sock, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:  # closed: the run is over
                return
            threading.Thread(target=self._greet, args=(sock,), daemon=True).start()

    def _greet(self, sock: socket.socket) -> None:
        """Authenticate a connection and hand it to the slot whose actor it is (actors connect in any order)."""
        sock.settimeout(None)
        _set_timeouts(sock, HANDSHAKE_TIMEOUT_S)
        conn = Connection(sock.detach())
        try:
            deliver_challenge(conn, self._authkey)
            answer_challenge(conn, self._authkey)
            token, node_id, node_ip, pid = conn.recv()
        except Exception:  # a stranger, a reset, a timeout, a malformed hello: not one of ours
            conn.close()
            return
        with socket.socket(fileno=os.dup(conn.fileno())) as same:  # a duplicate of the descriptor, one socket
            same.setblocking(True)  # (a default timeout set by anyone would make the shared socket non-blocking)
            _set_timeouts(same, MESSAGE_TIMEOUT_S)
        with self._lock:
            handle = self._expected.pop(token, None)
        if handle is None:  # an actor whose slot has given up on it
            conn.close()
            return
        handle.node_id, handle.node_ip, handle.pid, handle.conn = node_id, node_ip, pid, conn
        handle.arrived.set()

    def start(self, slot: Slot) -> None:
        token = secrets.token_hex(8)
        actor = self._actor_class.options(scheduling_strategy="SPREAD").remote()
        handle = ActorHandle(self._ray, actor, token)
        with self._lock:
            self._expected[token] = handle
        serving = actor.serve.remote(self._address, self._authkey, token, self.settings)
        handle.watcher = threading.Thread(target=handle.watch, args=(serving,), daemon=True)
        handle.watcher.start()
        slot.process, slot.conn, slot.item, slot.task_key = handle, None, None, None

    def message_within(self, slot: Slot, timeout: float) -> bool:
        """Wait for the actor to be placed and connect, then for its first message; EOFError once Ray says it
        is gone (a frozen node's connection never closes)."""
        deadline = time.monotonic() + timeout
        handle = slot.process
        while not handle.arrived.wait(0.2):
            if not handle.is_alive():
                raise EOFError
            if time.monotonic() > deadline:
                raise SimulatorUnavailable(
                    f"a Ray simulator actor did not start within {timeout:g} s (no node can place it, "
                    "or its node cannot reach this one's address)"
                )
        slot.conn = handle.conn
        while not slot.conn.poll(0.5):
            if not handle.is_alive():
                raise EOFError
            if time.monotonic() > deadline:
                return False
        return True

    def lost_reason(self, slot: Slot) -> str:
        handle = slot.process
        why = handle.lost_because or "its connection closed or stalled"
        return f"the Ray actor on node {handle.node_ip} was lost ({why})"

    def restart(self, slot: Slot) -> None:
        """A new actor wherever a CPU is free; none within ``FREE_CPU_WAIT_S``: the slot is retired."""
        self._drop(slot)
        deadline = time.monotonic() + FREE_CPU_WAIT_S
        while self._ray.available_resources().get("CPU", 0) < 1:
            if time.monotonic() > deadline:
                slot.retired = True
                return
            time.sleep(0.5)
        try:
            super().restart(slot)
        except VersionMismatch:
            raise
        except SimulatorUnavailable as exc:  # it could not start: the run goes on with fewer workers
            print(f"conflictbench: a replacement simulator worker could not start ({exc}); going on without it",
                  file=sys.stderr)  # fmt: skip
            self._drop(slot)
            slot.retired = True

    def _drop(self, slot: Slot) -> None:
        if slot.process is not None:
            with self._lock:
                self._expected.pop(slot.process.token, None)
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
        self._closing = True
        if self._server is not None:
            self._server.close()
        if self._owns_ray and self._ray.is_initialized():
            self._ray.shutdown()


def connect(ray: Any, address: str | None) -> None:
    """``ray.init`` with one clear line for a ``host:port`` nobody answers (Ray itself retries for minutes)."""
    where = address if address not in (None, "auto") else os.environ.get("RAY_ADDRESS")
    target = gcs_target(where)
    if target:
        try:
            socket.create_connection(target, timeout=5).close()
        except OSError:
            raise SimulatorUnavailable(f"cannot reach the Ray cluster at {where!r} (its head's GCS port)") from None
    try:
        ray.init(address=address, logging_level=logging.WARNING, include_dashboard=False)
    except (ConnectionError, ValueError, RuntimeError, SystemExit) as exc:
        raise SimulatorUnavailable(f"cannot connect to Ray ({where or 'a new local instance'}): {exc}") from None


def gcs_target(address: str | None) -> tuple[str, int] | None:
    """(host, port) of a ``host:port`` or ``[v6]:port`` address; None for what Ray resolves itself
    (``ray://...``, ``local``, ``auto``, nothing)."""
    found = re.fullmatch(r"\[?([^\[\]/]+?)\]?:(\d+)", address or "")
    return (found[1], int(found[2])) if found else None


def _set_timeouts(sock: socket.socket, seconds: float) -> None:
    """Kernel-level timeouts, so they hold for the raw reads and writes of a ``Connection`` on this socket."""
    value = struct.pack("ll", int(seconds), int((seconds % 1) * 1e6))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, value)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, value)
