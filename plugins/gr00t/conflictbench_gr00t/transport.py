"""One ZeroMQ REQ socket to a GR00T policy server (NVIDIA's ``run_gr00t_server.py`` or ours), for the shared client.

The shared client (``conflictbench.PolicyClient``) makes one per simulator worker and owns retries and
reconnection; this class only speaks the protocol (see :mod:`.protocol`). ZeroMQ connects lazily and a REQ
socket is lockstep, so ``connect`` proves the server is there with a ``ping`` and then asks for our metadata
endpoint (NVIDIA's server answers it with an error: then ``metadata`` stays empty), and a request that times
out closes the socket (the next request reconnects). ``{"error": ...}`` replies are the server's errors:
:class:`InfrastructureError`.
"""

from __future__ import annotations

import urllib.parse
from typing import Any

import zmq

from conflictbench import InfrastructureError, Transport, UserError
from conflictbench.core.transport import one_line

from .protocol import ERROR, METADATA, PING, endpoint_request, packb, unpackb


class Gr00tTransport(Transport):
    """GR00T's ZeroMQ protocol on one REQ socket; ``metadata`` is what our server says it hosts ({} otherwise)."""

    def __init__(self, url: str, api_token: str | None = None):
        super().__init__(url)
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "tcp" or not parts.hostname or parts.port is None:
            raise UserError(f"not a tcp://HOST:PORT URL: {url!r} (a GR00T server, e.g. tcp://gpu-box:5555)")
        self.api_token = api_token
        self.metadata: dict[str, Any] = {}
        self._context = zmq.Context.instance()
        self._socket: zmq.Socket | None = None

    def connect(self, timeout: float) -> None:
        self.close()
        socket = self._context.socket(zmq.REQ)
        socket.setsockopt(zmq.LINGER, 0)
        socket.connect(self.url)
        self._socket = socket
        try:
            self._call(endpoint_request(PING, self.api_token), timeout)
        except TimeoutError:
            self.close()
            raise TimeoutError(f"no GR00T server answered a ping within {timeout:g} s") from None
        except InfrastructureError as exc:
            self.close()
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
        try:
            # A REQ socket with no server behind it blocks on send; one that sent must receive before it can
            # send again: either wait ends the socket, and the next request starts over.
            if not socket.poll(milliseconds, zmq.POLLOUT):
                self.close()
                raise TimeoutError(f"no server took the request within {timeout:g} s")
            socket.send(payload)
            if not socket.poll(milliseconds, zmq.POLLIN):
                self.close()
                raise TimeoutError(f"no answer within {timeout:g} s")
            message = socket.recv()
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

    def close(self) -> None:
        socket, self._socket = self._socket, None
        if socket is not None:
            socket.close(linger=0)
