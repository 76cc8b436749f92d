"""What a server accepts from a peer: the shared token, and the bounds on messages, connections and queued requests.

Every server of ours (websocket, REST, ZeroMQ) takes a :class:`Guard`; one not given one uses the process-wide guard
(:func:`current`), which ``conflictbench-serve`` sets once from its options and environment (:func:`configure`).
Clients use the same message bound for the replies they read.

The message bound is derived from what the protocols legitimately carry (README, "Security"): a request holds one
observation per batch row, at most :data:`CAMERAS` RGB uint8 images of at most :data:`IMAGE_SIDE` squared pixels
plus a state of a few floats; REST's json-numpy sends an array's bytes as base64 (4/3 of them); a reply holds an
action chunk (a few hundred steps of at most 32 floats: under 100 kB) and the metadata (a few kB). So

    max_message_bytes = REQUEST_ROWS x CAMERAS x IMAGE_SIDE**2 x 3 x 4/3
                      = 4 x 3 x 512**2 x 3 x 4/3 = 12 MiB

which leaves room for a request of up to :data:`REQUEST_ROWS` rows (our clients and LIBERO's send one; starVLA's
format allows several), while one frame can no longer make a server read hundreds of MiB.
"""

from __future__ import annotations

import dataclasses
import hmac
import os

TOKEN_VARIABLE = "CONFLICTBENCH_SERVER_TOKEN"  # env var a server reads its token from (never argv: ps shows argv)
#: How the token travels on websockets and REST, as openpi-client sends its API key: ``Authorization: Api-Key <token>``
#: (on the websocket upgrade, on every HTTP request). GR00T's ZeroMQ requests carry it as their ``api_token`` field.
AUTHORIZATION, SCHEME = "Authorization", "Api-Key"
#: What our websocket and REST servers answer a request without the token (ZeroMQ answers NVIDIA's own words,
#: ``Unauthorized: Invalid API token``, which GR00T's clients know).
UNAUTHORIZED = f"Unauthorized: this server needs its token ({AUTHORIZATION}: {SCHEME} ...)"
#: env var that sets ``max_message_bytes`` for servers and clients alike (a run and its servers must agree)
MESSAGE_LIMIT_VARIABLE = "CONFLICTBENCH_MAX_MESSAGE_BYTES"
#: The longest one-line error a server sends back.
ERROR_LINE_LIMIT = 500

CAMERAS = 3  # LIBERO's agent view, wrist and one more
IMAGE_SIDE = 512  # the largest render any plugin asks for (most use 224 or 256)
REQUEST_ROWS = 4  # rows one request may carry
BASE64 = 4 / 3  # json-numpy's expansion of an array's bytes


def message_bytes(rows: int = REQUEST_ROWS, cameras: int = CAMERAS, side: int = IMAGE_SIDE) -> int:
    """The largest message a request of ``rows`` observations of ``cameras`` RGB uint8 images of ``side``
    squared pixels needs, in every protocol (json-numpy's base64 included)."""
    return int(rows * cameras * side * side * 3 * BASE64)


DEFAULT_MAX_MESSAGE_BYTES = message_bytes()  # 12 MiB
DEFAULT_MAX_CONNECTIONS = 256  # comfortably above any run.workers one machine runs (each worker holds one)
DEFAULT_MAX_QUEUED = 512  # every connection may have a request waiting, twice over


@dataclasses.dataclass(frozen=True)
class Guard:
    """What a server accepts. ``token``: the shared secret every request must carry (None: none needed);
    ``max_message_bytes``: the largest frame, body or message read (also the replies a client reads);
    ``max_connections``: connections served at once (at least run.workers); ``max_queued``: requests waiting
    for the batcher (a full queue answers "busy")."""

    token: str | None = None
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES
    max_connections: int = DEFAULT_MAX_CONNECTIONS
    max_queued: int = DEFAULT_MAX_QUEUED

    def __post_init__(self) -> None:
        for name in ("max_message_bytes", "max_connections", "max_queued"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.max_queued < self.max_connections:
            raise ValueError(
                f"max_queued ({self.max_queued}) must be at least max_connections ({self.max_connections}): "
                "every connection may have a request waiting"
            )
        if self.token is not None and (not isinstance(self.token, str) or not self.token):
            raise ValueError("the server token must be a non-empty string (or None for none)")

    def admits(self, presented: str | bytes | None) -> bool:
        """Whether ``presented`` is the token (always, when no token is set); constant-time."""
        if self.token is None:
            return True
        if presented is None:
            return False
        if isinstance(presented, str):
            presented = presented.encode("utf-8", "surrogateescape")
        return hmac.compare_digest(presented, self.token.encode("utf-8"))

    def admits_header(self, authorization: str | None) -> bool:
        """Whether an ``Authorization`` header's value carries the token (``Api-Key <token>``)."""
        if self.token is None:
            return True
        scheme, _, presented = (authorization or "").strip().partition(" ")
        return scheme.lower() == SCHEME.lower() and self.admits(presented.strip())

    def __repr__(self) -> str:  # never print the token (logs, tracebacks)
        token = "None" if self.token is None else "'***'"
        return (
            f"Guard(token={token}, max_message_bytes={self.max_message_bytes}, "
            f"max_connections={self.max_connections}, max_queued={self.max_queued})"
        )


_current: Guard | None = None  # read from the environment on first use


def configure(**changes) -> Guard:
    """Set the process-wide guard (what servers use when given none) to the current one with ``changes``;
    returns it. Raising ``max_connections`` alone raises ``max_queued`` with it where it would fall short."""
    global _current
    _current = current()
    if "max_connections" in changes and "max_queued" not in changes:
        changes["max_queued"] = max(_current.max_queued, changes["max_connections"])
    _current = dataclasses.replace(_current, **changes)
    return _current


def current() -> Guard:
    """The process-wide guard: until :func:`configure` is called, the defaults with the token in
    :data:`TOKEN_VARIABLE` and the message bound in :data:`MESSAGE_LIMIT_VARIABLE`, where they are set."""
    global _current
    if _current is None:
        _current = Guard(token=token_from_environment(), max_message_bytes=message_limit_from_environment())
    return _current


def authorization(token: str | None) -> dict[str, str]:
    """The header a client sends with ``token`` (none without one)."""
    return {AUTHORIZATION: f"{SCHEME} {token}"} if token else {}


def one_line(text: str, limit: int = ERROR_LINE_LIMIT) -> str:
    """``text`` on one line, cut to ``limit`` characters: how every server of ours answers an error (a peer learns
    nothing of our internals; the traceback stays in the server's log)."""
    flat = " ".join(text.split())
    return flat if len(flat) <= limit else flat[: limit - 3] + "..."


def error_line(error: BaseException, bare: tuple[type[BaseException], ...] = ()) -> str:
    """``error`` as the one line a peer gets: ``TypeName: message``, or the message alone for the ``bare`` types
    (a protocol's invalid request, whose message is the answer)."""
    return one_line(str(error) if isinstance(error, bare) else f"{type(error).__name__}: {error}")


def token_from_environment() -> str | None:
    """The token in :data:`TOKEN_VARIABLE` (None when unset or empty)."""
    return os.environ.get(TOKEN_VARIABLE) or None


def message_limit_from_environment() -> int:
    """``max_message_bytes`` from :data:`MESSAGE_LIMIT_VARIABLE`, else the default; ValueError (one line) for a
    value that is not a positive integer."""
    text = os.environ.get(MESSAGE_LIMIT_VARIABLE, "").strip()
    if not text:
        return DEFAULT_MAX_MESSAGE_BYTES
    # ASCII digits only, as the run reads it (conflictbench.hosting.transport): int() alone would also take "+5",
    # "1_000" and other scripts' digits, and the two sides would disagree on the bound
    value = int(text) if text.isascii() and text.isdigit() else 0
    if value < 1:
        raise ValueError(f"{MESSAGE_LIMIT_VARIABLE} must be a positive number of bytes, got {text[:40]!r}")
    return value
