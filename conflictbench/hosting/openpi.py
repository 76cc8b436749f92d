"""openpi's websocket protocol, client side: one connection to an openpi policy server (openpi's own
``serve_policy.py``, starVLA's for VLA-JEPA, or ours from ``conflictbench-serving``).

The framing (openpi-client's ``websocket_client_policy``): the server's first frame is its metadata; then one
binary frame out and one back per request, each msgpack-numpy (``conflictbench_serving.msgpack_numpy``). A
text frame in reply is the server's error (openpi sends the traceback, then closes; ours one line):
:class:`InfrastructureError` with its last line, and the next request reconnects. What a request and a reply hold
is the model's (its plugin's ``protocol``).

``token`` travels on the upgrade as openpi-client sends its API key (``Authorization: Api-Key <token>``; a server
that refuses it, HTTP 401, raises :class:`PermissionError`: the client stops the run at once). Frames are bounded
both ways by ``max_message_bytes`` (default: ``$CONFLICTBENCH_MAX_MESSAGE_BYTES``, else 12 MiB): a larger request is
not sent, a larger reply not read (either is an :class:`InfrastructureError` naming the bound), and a request the
server finds too large (close code 1009) says so too.

The shared client (:class:`~.client.PolicyClient`) makes one per simulator worker and owns retries and
reconnection. Needs the ``openpi`` extra, ``conflictbench[openpi]``: ``websockets`` and ``conflictbench-serving``
(a plugin speaking the protocol requires it; without it, importing this module says so in one line).
"""

from __future__ import annotations

import inspect
import urllib.parse
from typing import Any

from ..core.errors import InfrastructureError, UserError
from .transport import Transport, authorization, extra_missing, message_limit, one_line, over_limit, refused_token

try:
    from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus, InvalidURI
    from websockets.sync.client import ClientConnection, connect

    from conflictbench_serving.msgpack_numpy import packb, unpackb
except ModuleNotFoundError as missing:
    raise extra_missing(__name__, "openpi", missing, install="./serving") from None

# websockets 17 wants ``legacy=True`` for a connection kept open outside a ``with`` block (the default
# then, with a deprecation warning); older releases have no such flag.
_KEEP_OPEN = {"legacy": True} if "legacy" in inspect.signature(connect).parameters else {}
# websockets >= 15 takes proxies from the environment; a server on this machine is reached directly.
_NO_PROXY = {"proxy": None} if "proxy" in inspect.signature(connect).parameters else {}
_LOOPBACK = ("127.0.0.1", "localhost", "::1")
_MESSAGE_TOO_BIG = 1009  # the close code of a frame over the receiver's max_size


class OpenpiTransport(Transport):
    """openpi's websocket protocol on one connection; ``metadata`` is the server's first frame."""

    def __init__(self, url: str, token: str | None = None, max_message_bytes: int | None = None):
        super().__init__(url)
        parts = urllib.parse.urlsplit(url)
        if parts.scheme not in ("ws", "wss") or not parts.hostname:
            raise UserError(f"not a ws:// or wss:// URL: {url!r} (an openpi server, e.g. ws://gpu-box:8000)")
        self.max_message_bytes = message_limit(max_message_bytes)
        self._headers = authorization(token)
        self._ws: ClientConnection | None = None
        self.metadata: dict[str, Any] = {}

    def connect(self, timeout: float) -> None:
        self.close()
        try:
            direct = _NO_PROXY if urllib.parse.urlsplit(self.url).hostname in _LOOPBACK else {}
            self._ws = connect(
                self.url,
                compression=None,
                max_size=self.max_message_bytes,
                additional_headers=self._headers or None,
                open_timeout=timeout,
                close_timeout=2,
                **_KEEP_OPEN,
                **direct,
            )
            first = self._ws.recv(timeout=timeout)
        except InvalidStatus as exc:
            self.close()
            if exc.response.status_code == 401:
                body = exc.response.body.decode(errors="replace") if exc.response.body else ""
                raise refused_token(self.url, f"HTTP 401 {body}") from None
            raise ConnectionError(f"{type(exc).__name__}: {exc}") from None  # e.g. 503, busy: try again later
        except (InvalidHandshake, InvalidURI, ConnectionClosed) as exc:
            self.close()
            raise ConnectionError(f"{type(exc).__name__}: {exc}") from None
        except BaseException:
            self.close()
            raise
        if isinstance(first, str):
            self.close()
            raise ConnectionError(f"the server's first frame is text, not openpi metadata: {one_line(first)}")
        try:
            metadata = unpackb(first)
        except Exception as exc:
            self.close()
            raise ConnectionError(f"the server's first frame is not openpi metadata: {exc}") from None
        self.metadata = metadata if isinstance(metadata, dict) else {}

    def exchange(self, request: Any, timeout: float) -> Any:
        if self._ws is None:
            raise ConnectionError("not connected")
        frame = packb(request)
        if len(frame) > self.max_message_bytes:
            raise over_limit(self.url, "a request", len(frame), self.max_message_bytes)
        try:
            self._ws.send(frame)
            reply = self._ws.recv(timeout=timeout)
        except ConnectionClosed as exc:
            self.close()
            limit, server_first = self.max_message_bytes, bool(exc.rcvd_then_sent)  # who closed first
            if server_first and exc.rcvd is not None and exc.rcvd.code == _MESSAGE_TOO_BIG:  # it refused our request
                raise InfrastructureError(
                    f"{self.url} refused a request of {len(frame)} bytes as too big ({one_line(exc.rcvd.reason)}): "
                    "the server's limit (conflictbench-serve --max-message-mib) is lower than this run's"
                ) from None
            if not server_first and exc.sent is not None and exc.sent.code == _MESSAGE_TOO_BIG:  # we refused its reply
                raise over_limit(self.url, "a reply", f"more than {limit}", limit) from None
            raise ConnectionError(f"the connection closed: {exc}") from None
        if isinstance(reply, str):  # openpi's error reply; the server closes this connection after it
            self.close()
            last = reply.strip().splitlines()[-1] if reply.strip() else "(empty)"  # a traceback ends with the error
            raise InfrastructureError(f"{self.url} answered an error: {one_line(last)}")
        try:
            return unpackb(reply)
        except Exception as exc:  # not the model's behaviour: the wire carried something else
            raise InfrastructureError(f"{self.url} sent a frame that is not openpi msgpack: {exc}") from None

    def close(self) -> None:
        ws, self._ws = self._ws, None
        if ws is not None:
            try:
                ws.close()
            except Exception:  # closing a broken connection: nothing more to do
                pass
