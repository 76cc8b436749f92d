"""Transports for served policies: one connection to a policy server in one wire protocol.

A model plugin brings its own (openpi's websocket, GR00T's ZeroMQ); the one built in is HTTP POST
with a JSON body, the shape of the OpenVLA family's REST ``POST /act`` servers. The client in
:mod:`.client` makes one transport per stream and owns retries and reconnection.
"""

from __future__ import annotations

import http.client
import json
import socket
import urllib.parse
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from ..core.errors import InfrastructureError, UserError


class Transport(ABC):
    """One connection to a policy server in one wire protocol. The client makes one per stream.

    Raise :class:`OSError` when the connection cannot be made or breaks (the client retries and
    reconnects), :class:`InfrastructureError` when the server answers with an error.
    """

    def __init__(self, url: str):
        self.url = url

    @abstractmethod
    def connect(self, timeout: float) -> None:
        """Open the connection (and do the protocol's handshake), within ``timeout`` seconds."""

    @abstractmethod
    def exchange(self, request: Any, timeout: float) -> Any:
        """Send one request on the open connection and return the server's reply."""

    def close(self) -> None:  # noqa: B027 (optional to override: a transport may hold nothing to close)
        """Close the connection; must not raise, also when it was never opened."""


class HttpJsonTransport(Transport):
    """HTTP POST of a JSON body, JSON reply, on one keep-alive connection (``http.client``).

    numpy arrays and scalars in the request are sent as (nested) lists and numbers. A reply with a
    status of 400 or more, or a JSON object whose only key is ``error``, raises
    :class:`InfrastructureError`. A protocol with another JSON dialect (json-numpy's arrays) overrides
    :meth:`dumps` and :meth:`loads`.
    """

    def __init__(self, url: str):
        super().__init__(url)
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise UserError(f"not an http:// or https:// URL: {url!r}")
        self._connection_class = http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
        self._host, self._port = parts.hostname, parts.port
        self._path = (parts.path or "/") + (f"?{parts.query}" if parts.query else "")
        self._conn: http.client.HTTPConnection | None = None
        self._connect_timeout = 10.0

    def connect(self, timeout: float) -> None:
        self.close()
        self._connect_timeout = timeout
        self._conn = self._connection_class(self._host, self._port, timeout=timeout)
        self._conn.connect()
        self._conn.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # small requests: no Nagle wait

    def dumps(self, request: Any) -> str:
        """The request's JSON text."""
        return json.dumps(request, default=_json_default)

    def loads(self, text: bytes) -> Any:
        """The reply's JSON text read (raise ValueError where it is not JSON)."""
        return json.loads(text)

    def exchange(self, request: Any, timeout: float) -> Any:
        body = self.dumps(request).encode()
        conn = self._conn
        if conn is None:
            raise ConnectionError("not connected")
        if conn.sock is None:  # the server closed it after the last reply ("Connection: close")
            try:
                self.connect(self._connect_timeout)
            except OSError as exc:  # not a slow reply: the client reconnects with its back-off
                raise ConnectionError(f"reconnecting after the server closed the connection: {exc}") from exc
            conn = self._conn
        conn.sock.settimeout(timeout)
        try:
            conn.request("POST", self._path, body, {"Content-Type": "application/json"})
            response = conn.getresponse()
            data = response.read()
        except http.client.HTTPException as exc:  # a cut or garbled reply: this connection is done
            raise ConnectionError(f"{type(exc).__name__}: {exc}") from exc
        if response.status >= 400:
            raise InfrastructureError(
                f"{self.url} answered HTTP {response.status} {response.reason}: "
                f"{one_line(data.decode(errors='replace'))}"
            )
        try:
            reply = self.loads(data)
        except ValueError:
            raise InfrastructureError(
                f"{self.url} answered something that is not JSON: {one_line(data.decode(errors='replace'))}"
            ) from None
        if isinstance(reply, dict) and list(reply) == ["error"]:
            raise InfrastructureError(f"{self.url} answered an error: {one_line(str(reply['error']))}")
        return reply

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line, cut to ``limit`` characters (server messages go into one-line errors)."""
    flat = " ".join(text.split())
    return flat if len(flat) <= limit else flat[: limit - 3] + "..."


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} cannot be sent as JSON")


def extra_missing(module: str, extra: str, error: ModuleNotFoundError, install: str = "") -> ModuleNotFoundError:
    """What a protocol module raises when a library of its extra is not installed: one line naming the extra
    (``conflictbench[extra]``, which the plugins that speak the protocol require) and how to install it;
    ``install`` adds what the extra needs from a checkout (``./serving``: conflictbench-serving is not on PyPI)."""
    where = f"pip install '.[{extra}]'{f' {install}' if install else ''} in a checkout"
    return ModuleNotFoundError(f"{module} needs conflictbench[{extra}] ({error}): {where}", name=error.name)
