"""Transports for served policies: one connection to a policy server in one wire protocol.

A model plugin brings its own (openpi's websocket, GR00T's ZeroMQ); the one built in is HTTP POST
with a JSON body, the shape of the OpenVLA family's REST ``POST /act`` servers. The client in
:mod:`.client` makes one transport per stream and owns retries and reconnection.
"""

from __future__ import annotations

import http.client
import json
import os
import socket
import urllib.parse
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from ..core.errors import InfrastructureError, UserError

#: The largest reply a client reads, and request it sends: conflictbench_serving.guard's bound (12 MiB: four rows of
#: three 512 x 512 RGB cameras, base64'd), set for servers and clients alike by the same variable. Restated here:
#: the built-in transport needs nothing but the standard library (a test keeps the two equal).
MESSAGE_LIMIT_VARIABLE = "CONFLICTBENCH_MAX_MESSAGE_BYTES"
DEFAULT_MAX_MESSAGE_BYTES = 12 * 2**20
#: How a request carries the server's token on websockets and HTTP, as openpi-client sends its API key.
AUTHORIZATION, SCHEME = "Authorization", "Api-Key"


def message_limit(given: int | None = None) -> int:
    """``given``, else ``$CONFLICTBENCH_MAX_MESSAGE_BYTES``, else the default; :class:`UserError` for a bad value."""
    if given is not None:
        value, text = given, str(given)
    else:
        text = os.environ.get(MESSAGE_LIMIT_VARIABLE, "").strip()
        if not text:
            return DEFAULT_MAX_MESSAGE_BYTES
        value = int(text) if text.isascii() and text.isdigit() else 0  # as the servers read it (guard.py)
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        setting = f"{MESSAGE_LIMIT_VARIABLE} (max_message_bytes)"
        raise UserError(f"{setting} must be a positive number of bytes, got {text[:40]!r}")
    return value


def authorization(token: str | None) -> dict[str, str]:
    """The header that carries ``token`` (none without one)."""
    return {AUTHORIZATION: f"{SCHEME} {token}"} if token else {}


def over_limit(url: str, what: str, size: int | str, limit: int) -> InfrastructureError:
    """The one line for a message over the bound: which, how large, the bound and the setting that moves it."""
    return InfrastructureError(
        f"{url}: {what} of {size} bytes is over the limit of {limit} bytes (max_message_bytes; raise it with "
        f"{MESSAGE_LIMIT_VARIABLE} for the run, and conflictbench-serve --max-message-mib for the server)"
    )


def refused_token(url: str, detail: str) -> PermissionError:
    """What a transport raises when the server refused our token or its absence (HTTP 401, ``Unauthorized``): the
    client never asks again with the same token, it stops the run in one line (:mod:`.client`)."""
    return PermissionError(f"{url} refused this run's token: {one_line(detail)}")


class UnreadableReply(ValueError):
    """A reply that is JSON but holds something the protocol refuses to read (json-numpy's unsafe array): what
    :meth:`HttpJsonTransport.loads` raises so the one-line error keeps the reason (a plain ValueError there means
    "not JSON")."""


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
    :class:`InfrastructureError`; so does a reply over ``max_message_bytes`` (read no further) and a request over
    it (not sent). ``token``: sent on every request (``Authorization: Api-Key <token>``); a server that answers
    HTTP 401 raises :class:`PermissionError` (the client stops the run at once). A protocol with another JSON
    dialect (json-numpy's arrays) overrides :meth:`dumps` and :meth:`loads`.
    """

    def __init__(self, url: str, token: str | None = None, max_message_bytes: int | None = None):
        super().__init__(url)
        self.max_message_bytes = message_limit(max_message_bytes)
        self._headers = authorization(token)
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
        """The reply's JSON text read (raise ValueError where it is not JSON, :class:`UnreadableReply` where it holds
        what the protocol refuses)."""
        return json.loads(text)

    def exchange(self, request: Any, timeout: float) -> Any:
        body = self.dumps(request).encode()
        if len(body) > self.max_message_bytes:
            raise over_limit(self.url, "a request", len(body), self.max_message_bytes)
        conn = self._conn
        if conn is None:
            raise ConnectionError("not connected")
        if conn.sock is None:  # the server closed it after the last reply ("Connection: close")
            try:
                self.connect(self._connect_timeout)
            except OSError as exc:  # not a slow reply: the client reconnects with its back-off
                raise ConnectionError(f"reconnecting after the server closed the connection: {exc}") from exc
            conn = self._conn
        conn.timeout = timeout  # a server that closed after its handshake's reply: http.client opens a new socket
        if conn.sock is not None:
            conn.sock.settimeout(timeout)
        try:
            conn.request("POST", self._path, body, {"Content-Type": "application/json", **self._headers})
            response = conn.getresponse()
            data = self.read_reply(response)
        except http.client.HTTPException as exc:  # a cut or garbled reply: this connection is done
            raise ConnectionError(f"{type(exc).__name__}: {exc}") from exc
        if response.status == 401:
            raise refused_token(self.url, f"HTTP 401 {data.decode(errors='replace')}")
        if response.status >= 400:
            raise InfrastructureError(
                f"{self.url} answered HTTP {response.status} {response.reason}: "
                f"{one_line(data.decode(errors='replace'))}"
            )
        try:
            reply = self.loads(data)
        except UnreadableReply as exc:
            raise InfrastructureError(f"{self.url} answered {one_line(str(exc))}") from None
        except ValueError:
            raise InfrastructureError(
                f"{self.url} answered something that is not JSON: {one_line(data.decode(errors='replace'))}"
            ) from None
        if isinstance(reply, dict) and list(reply) == ["error"]:
            raise InfrastructureError(f"{self.url} answered an error: {one_line(str(reply['error']))}")
        return reply

    def read_reply(self, response: http.client.HTTPResponse) -> bytes:
        """The reply's body, read no further than ``max_message_bytes`` (its ``Content-Length`` checked first)."""
        limit = self.max_message_bytes
        declared = response.getheader("Content-Length", "")
        if declared.strip().isdigit() and int(declared) > limit:
            self.close()  # the rest of that reply is never read: this connection is done
            raise over_limit(self.url, "a reply", int(declared), limit)
        data = response.read(limit + 1)
        if len(data) > limit:
            self.close()
            raise over_limit(self.url, "a reply", f"more than {limit}", limit)
        response.read()  # the end of a chunked reply (nothing more: the bound was not reached)
        return data

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None


def one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line, cut to ``limit`` characters (server messages go into one-line errors). The servers'
    own is ``conflictbench_serving.guard.one_line``: the run's built-in transport needs only the standard library."""
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
