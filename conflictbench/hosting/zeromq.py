"""NVIDIA Isaac-GR00T's ZeroMQ protocol, client side: one REQ socket to a GR00T policy server (NVIDIA's
``run_gr00t_server.py`` or ours, ``conflictbench_serving.zeromq``, which also holds the protocol's codec).

The shared client (:class:`~.client.PolicyClient`) makes one per simulator worker and owns retries and
reconnection; this class only speaks the protocol; what a ``get_action`` request holds is the model's (its
plugin's ``protocol``). Needs the ``zeromq`` extra, ``conflictbench[zeromq]``: ``pyzmq`` and
``conflictbench-serving``. ZeroMQ connects lazily and a REQ socket is lockstep, so ``connect`` proves the server
is there with a ``ping`` and then asks for our metadata endpoint (NVIDIA's server answers it with an error: then
``metadata`` stays empty), and a request that times out closes the socket (the next request reconnects). ZeroMQ
hides a dropped TCP connection, so a socket monitor watches for it: a server that dies while a request waits is a
lost connection (the client reconnects and sends it again, or stops the run), not a slow model. ``{"error":
...}`` replies are the server's errors: :class:`InfrastructureError`; a server that refuses our ``api_token``
(``Unauthorized``, NVIDIA's answer and ours) raises :class:`PermissionError`: the client stops the run at once.
Messages are bounded both ways by ``max_message_bytes`` (default: ``$CONFLICTBENCH_MAX_MESSAGE_BYTES``, else 12 MiB):
a larger request is not sent (:class:`InfrastructureError` naming the bound); a larger reply is dropped by ZeroMQ
(``MAXMSGSIZE``) before it is read, which the monitor sees as a dropped connection.
"""

from __future__ import annotations

import socket as net
import time
import urllib.parse
from typing import Any

from ..core.errors import InfrastructureError, UserError
from .transport import Transport, extra_missing, message_limit, one_line, over_limit, refused_token

try:
    import zmq
    from zmq.utils.monitor import recv_monitor_message

    from conflictbench_serving.zeromq import ERROR, METADATA, PING, endpoint_request, packb, unpackb
except ModuleNotFoundError as missing:
    raise extra_missing(__name__, "zeromq", missing, install="./serving") from None


class ZmqTransport(Transport):
    """GR00T's ZeroMQ protocol on one REQ socket; ``metadata`` is what our server says it hosts ({} otherwise)."""

    def __init__(self, url: str, api_token: str | None = None, max_message_bytes: int | None = None):
        super().__init__(url)
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "tcp" or not parts.hostname or parts.port is None:
            raise UserError(f"not a tcp://HOST:PORT URL: {url!r} (a GR00T server, e.g. tcp://gpu-box:5555)")
        self.api_token = api_token
        self.max_message_bytes = message_limit(max_message_bytes)
        self.metadata: dict[str, Any] = {}
        self._context = zmq.Context.instance()
        self._socket: zmq.Socket | None = None
        self._monitor: zmq.Socket | None = None

    def connect(self, timeout: float) -> None:
        self.close()
        # ZeroMQ connects in the background and would wait out the whole timeout on a closed port: a plain TCP
        # connection first says at once that nobody listens (connection refused), as HTTP and websockets do.
        parts = urllib.parse.urlsplit(self.url)
        net.create_connection((parts.hostname, parts.port), timeout=timeout).close()
        socket = self._context.socket(zmq.REQ)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, self.max_message_bytes)  # a larger reply: dropped before it is read
        self._monitor = socket.get_monitor_socket(zmq.EVENT_DISCONNECTED)
        socket.connect(self.url)
        self._socket = socket
        try:
            self._call(endpoint_request(PING, self.api_token), timeout)
        except TimeoutError:
            self.close()
            raise TimeoutError(f"no GR00T server answered a ping within {timeout:g} s") from None
        except InfrastructureError as exc:
            self.close()
            if "Unauthorized" in str(exc):  # NVIDIA's server and ours: no retry can change it
                raise refused_token(self.url, str(exc)) from None
            raise ConnectionError(f"the server at {self.url} refused a ping: {exc}") from None
        try:
            metadata = self._call(endpoint_request(METADATA, self.api_token), timeout)
        except InfrastructureError:  # NVIDIA's server: "Unknown endpoint"; it says nothing about its model
            metadata = {}
        self.metadata = metadata if isinstance(metadata, dict) else {}

    def exchange(self, request: Any, timeout: float) -> Any:
        if self._socket is None:
            raise ConnectionError("not connected")
        return self._call(request, timeout)

    def _call(self, request: Any, timeout: float) -> Any:
        socket = self._socket
        assert socket is not None
        milliseconds = max(1, int(timeout * 1000))
        payload = packb(request)
        if len(payload) > self.max_message_bytes:
            raise over_limit(self.url, "a request", len(payload), self.max_message_bytes)
        try:
            # A REQ socket with no server behind it blocks on send (nothing was sent: safe to send again once
            # reconnected); one that sent must receive before it can send again: either way the socket ends.
            if not socket.poll(milliseconds, zmq.POLLOUT):
                self.close()
                raise ConnectionError(f"no server took the request within {timeout:g} s")
            socket.send(payload)
            message = self._receive(milliseconds, timeout)
        except zmq.ZMQError as exc:
            self.close()
            raise ConnectionError(f"ZeroMQ: {exc}") from None
        if message == b"ERROR":  # NVIDIA's client treats this bare reply as a server error too
            raise InfrastructureError(f"{self.url} answered ERROR")
        try:
            reply = unpackb(message)
        except Exception as exc:  # not the model's behaviour: the wire carried something else
            raise InfrastructureError(f"{self.url} sent a message that is not GR00T msgpack: {exc}") from None
        if isinstance(reply, dict) and ERROR in reply:
            raise InfrastructureError(f"{self.url} answered an error: {one_line(str(reply[ERROR]))}")
        return reply

    def _receive(self, milliseconds: int, timeout: float) -> bytes:
        """The reply, or ConnectionError when the server's connection drops first, TimeoutError when none comes."""
        poller = zmq.Poller()
        poller.register(self._socket, zmq.POLLIN)
        poller.register(self._monitor, zmq.POLLIN)
        deadline = time.monotonic() + milliseconds / 1000
        while (left := deadline - time.monotonic()) > 0:
            ready = dict(poller.poll(max(1, int(left * 1000))))
            if self._socket in ready:
                return self._socket.recv()
            if self._monitor in ready and recv_monitor_message(self._monitor)["event"] == zmq.EVENT_DISCONNECTED:
                self.close()
                raise ConnectionError(  # ZeroMQ drops a reply over MAXMSGSIZE the same way, unread
                    "the server closed the connection before it answered (or its reply was over this run's "
                    f"max_message_bytes, {self.max_message_bytes} bytes: CONFLICTBENCH_MAX_MESSAGE_BYTES)"
                )
        self.close()
        raise TimeoutError(f"no answer within {timeout:g} s")

    def close(self) -> None:
        socket, self._socket = self._socket, None
        monitor, self._monitor = self._monitor, None
        if socket is not None:
            socket.disable_monitor()
            socket.close(linger=0)
        if monitor is not None:
            monitor.close(linger=0)


def answers_ping(url: str, api_token: str | None = None, timeout: float = 1.0) -> bool:
    """Whether a GR00T server at ``url`` answers a ping now (how a started server is known to be ready)."""
    transport = ZmqTransport(url, api_token=api_token)
    try:
        transport.connect(timeout=timeout)
        return transport.exchange(endpoint_request(PING, api_token), timeout=timeout).get("status") == "ok"
    except (OSError, InfrastructureError):  # a refused token (PermissionError) is no answer either
        return False
    finally:
        transport.close()
