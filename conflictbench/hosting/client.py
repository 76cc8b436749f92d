"""The shared client for policies whose model runs behind a server (every model plugin uses it).

A model plugin supplies what is particular to its model: a :class:`Transport` (its wire protocol:
connect, exchange one request for one reply, close) and ``encode``/``decode`` (observation to
request, reply to actions). The core owns the rest, the same for every model:

- a connection per stream (``observation.stream``, one per simulator worker), so N workers keep N
  requests in flight, and ``act_batch`` sends a batch's requests concurrently;
- connecting with a timeout, retried with exponential backoff; a connection lost mid-request is
  reopened and the request sent again (a few times at most);
- classification of failures. A server that cannot be reached after the retries raises
  :class:`ServerUnavailable`: the run stops, with one line naming the URL (exit code 3). A server
  error reply, a reply that cannot be read, no reply in time, or a connection that keeps dying on
  one request raise :class:`InfrastructureError`: that episode is stored with the error, left out
  of the measures, and played again by the next run.

Transports signal a broken or refused connection with :class:`OSError` (``ConnectionError``,
``TimeoutError``, socket errors) and a server's error reply with :class:`InfrastructureError`; a server that
refuses the token sent (or its absence: HTTP 401, GR00T's "Unauthorized") with :class:`PermissionError`, which is
never retried: the run stops at once with one line saying where the token comes from.
:class:`HttpJsonTransport` (HTTP POST with a JSON body, stdlib only) is the one built in; a
dialect overrides its ``dumps``/``loads`` (the OpenVLA family's ``POST /act`` needs json-numpy arrays:
:class:`~.rest.JsonNumpyTransport`, ``conflictbench[rest]``).

Example, a complete plugin module (``conflictbench model=mymodel model.server=http://gpu:8000/act``)::

    from dataclasses import dataclass

    import numpy as np

    from conflictbench import PolicyClient, ServedPolicy, ServingConfig, hookimpl


    @dataclass
    class MyModelConfig(ServingConfig):
        server: str = "http://127.0.0.1:8000/act"


    class MyModel(ServedPolicy):
        needs_images = True

        def encode(self, observation):
            return {"image": observation.agentview_image[::-1, ::-1],  # arrays are sent as lists
                    "instruction": observation.instruction}

        def decode(self, reply, observation):
            return np.asarray(reply, dtype=np.float64)  # (7,) or a chunk (k, 7)


    @hookimpl
    def conflictbench_register_policies(register):
        register("mymodel", load=lambda cfg: MyModel(PolicyClient.from_config(cfg)), config=MyModelConfig)

Another protocol passes its own transport: ``PolicyClient.from_config(cfg, transport=MyWebsocket)``.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..core.errors import ClientError, InfrastructureError, PolicyError, ServerUnavailable, UserError
from ..core.records import Observation
from .transport import HttpJsonTransport, Transport, one_line

#: What a run says of a token a server refused (the run never shows the token itself).
TOKEN_HINT = (
    "the server refused this run's token or its absence: set CONFLICTBENCH_SERVER_TOKEN, or model.token_file=PATH, "
    "to the token the server was started with"
)
#: Threads that carry concurrent requests (created on demand; one per stream in flight).
MAX_CONCURRENT_REQUESTS = 256


@dataclass
class ServingConfig:
    """Settings of a served policy; a plugin's config dataclass inherits them (``model.server=URL``).

    They say where and how patiently to reach the server, not what the model does, so they are no
    part of an episode's identity (``identity_exempt``): a server moved to another address resumes
    the same run. Name the model itself (its checkpoint) in a setting of the plugin's own.
    """

    identity_exempt: ClassVar[tuple[str, ...]] = (
        "server",
        "connect_timeout_s",
        "request_timeout_s",
        "connect_retries",
        "backoff_s",
        "max_backoff_s",
        "resends",
    )

    server: str = "http://127.0.0.1:8000/act"
    """Where the policy server listens."""
    connect_timeout_s: float = 10.0
    """Limit for opening one connection."""
    request_timeout_s: float = 120.0
    """Limit for the reply to one request (a large model on a slow device can take many seconds)."""
    connect_retries: int = 5
    """Further connection attempts before the run stops (after 0.5, 1, 2, 4, 8 s by default)."""
    backoff_s: float = 0.5
    """Wait before the first retry; doubled for each next one, up to ``max_backoff_s``."""
    max_backoff_s: float = 8.0
    resends: int = 2
    """How often one request is sent again after its connection broke, before the episode fails."""


class PolicyClient:
    """Requests to one policy server: a connection per stream, retries, reconnects, failure classes."""

    def __init__(
        self,
        url: str,
        transport: Callable[[str], Transport] = HttpJsonTransport,
        *,
        connect_timeout_s: float = 10.0,
        request_timeout_s: float = 120.0,
        connect_retries: int = 5,
        backoff_s: float = 0.5,
        max_backoff_s: float = 8.0,
        resends: int = 2,
    ):
        if connect_retries < 0 or resends < 0:
            raise UserError("connect_retries and resends must be >= 0")
        self.url, self._make_transport = url, transport
        self.connect_timeout_s, self.request_timeout_s = connect_timeout_s, request_timeout_s
        self.connect_retries, self.backoff_s, self.max_backoff_s = connect_retries, backoff_s, max_backoff_s
        self.resends = resends
        transport(url).close()  # a malformed URL fails here, before anything is started
        self._streams: dict[int, _Stream] = {}
        self._lock = threading.Lock()
        self._pool: ThreadPoolExecutor | None = None

    @classmethod
    def from_config(cls, cfg: ServingConfig, transport: Callable[[str], Transport] = HttpJsonTransport) -> PolicyClient:
        return cls(
            cfg.server,
            transport,
            connect_timeout_s=cfg.connect_timeout_s,
            request_timeout_s=cfg.request_timeout_s,
            connect_retries=cfg.connect_retries,
            backoff_s=cfg.backoff_s,
            max_backoff_s=cfg.max_backoff_s,
            resends=cfg.resends,
        )

    def backoff_delays(self) -> list[float]:
        """The waits between connection attempts."""
        return [min(self.backoff_s * 2**i, self.max_backoff_s) for i in range(self.connect_retries)]

    def _stream(self, stream: int) -> _Stream:
        with self._lock:
            if stream not in self._streams:
                self._streams[stream] = _Stream(self, self._make_transport(self.url))
            return self._streams[stream]

    def open(self, stream: int = 0) -> Transport:
        """Connect ``stream`` now (so a missing server stops a run before any simulator starts).

        Returns its connected transport, whose handshake a plugin may read (openpi's server metadata).
        """
        connection = self._stream(stream)
        connection.ensure_connected()
        return connection.transport

    def request(self, request: Any, stream: int = 0) -> Any:
        """One request on ``stream``'s connection; its reply, or InfrastructureError / ServerUnavailable."""
        return self._stream(stream).request(request)

    def request_many(self, requests: Sequence[tuple[int, Any]]) -> list[Any]:
        """``(stream, request)`` pairs sent concurrently, each on its stream's connection.

        Returns the replies in order, with an :class:`Exception` in place of each request that
        failed; raises :class:`ServerUnavailable` (after every request has ended) if any did.
        """
        if len(requests) == 1:
            calls = [_outcome(self.request, requests[0][1], requests[0][0])]
        else:
            with self._lock:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(MAX_CONCURRENT_REQUESTS, thread_name_prefix="conflictbench-serving")
                pool = self._pool
            calls = list(pool.map(lambda item: _outcome(self.request, item[1], item[0]), requests))
        unavailable = next((r for r in calls if isinstance(r, ServerUnavailable)), None)
        if unavailable is not None:
            raise unavailable
        return calls

    def close(self) -> None:
        with self._lock:
            streams, self._streams = list(self._streams.values()), {}
            pool, self._pool = self._pool, None
        for stream in streams:
            stream.transport.close()
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)


class _Stream:
    """One stream's connection; its lock keeps one request at a time on it."""

    def __init__(self, client: PolicyClient, transport: Transport):
        self.client, self.transport = client, transport
        self.connected = False
        self.lock = threading.Lock()

    def ensure_connected(self) -> None:
        with self.lock:
            self._connect()

    def _connect(self) -> None:
        if self.connected:
            return
        client, started = self.client, time.monotonic()
        delays = client.backoff_delays()
        for attempt in range(len(delays) + 1):
            try:
                self.transport.connect(client.connect_timeout_s)
                self.connected = True
                return
            except PermissionError as exc:  # asking again with the same token cannot help
                self.transport.close()
                raise ServerUnavailable(client.url, f"{one_line(str(exc))}; {TOKEN_HINT}") from None
            except OSError as exc:
                self.transport.close()
                reason = _describe(exc, client.connect_timeout_s)
                if attempt < len(delays):  # said at once: a run waiting on a server is never silent
                    print(f"conflictbench: {client.url}: {reason}; attempt {attempt + 1} of {len(delays) + 1}, "
                          f"trying again in {delays[attempt]:g} s", file=sys.stderr, flush=True)  # fmt: skip
                    time.sleep(delays[attempt])
        raise ServerUnavailable(
            client.url, f"{reason}; {len(delays) + 1} attempt(s) over {time.monotonic() - started:.1f} s"
        )

    def _drop(self) -> None:
        self.transport.close()
        self.connected = False

    def request(self, request: Any) -> Any:
        client = self.client
        with self.lock:
            for _ in range(client.resends + 1):
                self._connect()
                try:
                    return self.transport.exchange(request, client.request_timeout_s)
                except InfrastructureError:
                    self._drop()  # a server that answered with an error may have closed this connection
                    raise
                except TimeoutError:
                    self._drop()  # the server may still be working on it: never resend a slow request
                    raise InfrastructureError(
                        f"no reply from {client.url} within {client.request_timeout_s:g} s"
                    ) from None
                except OSError as exc:
                    self._drop()  # lost mid-request: reconnect (or stop the run) and send it again
                    reason = _describe(exc, client.request_timeout_s)
        raise InfrastructureError(
            f"the connection to {client.url} broke {client.resends + 1} times on one request "
            f"(last: {reason}); did the server run out of memory or crash on it?"
        )


class ServedPolicy:
    """A policy whose model runs behind a server. Subclasses define ``encode`` and ``decode``.

    One instance serves every simulator worker (it has ``act_batch``): each observation's
    ``stream`` picks its connection, and a batch's requests are in flight together. Per-episode
    state, if a protocol needs some, is kept by ``observation.stream`` (``observation.step == 0``
    starts an episode); the instruction arrives in every observation.
    """

    needs_images = True
    concurrent_requests = True  # act_batch is thread-safe per stream: the runner sends each query as it comes

    def __init__(self, client: PolicyClient):
        self.client = client
        client.open()

    def encode(self, observation: Observation) -> Any:
        """The request for one observation, as the transport sends it."""
        raise NotImplementedError

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        """The action (7,) or chunk (k, 7) in the server's reply to ``observation``'s request."""
        raise NotImplementedError

    def reset(self, instruction: str) -> None:
        pass

    def act(self, observation: Observation) -> np.ndarray:
        result = self.act_batch([observation])[0]
        if isinstance(result, Exception):
            raise result
        return result

    def act_batch(self, observations: Sequence[Observation]) -> list[Any]:
        """Actions in order; an :class:`Exception` in place of each observation whose request failed
        (that episode alone ends with it). Raises :class:`ServerUnavailable`."""
        encoded = [_outcome(self._encode, obs) for obs in observations]
        sendable = [i for i, e in enumerate(encoded) if not isinstance(e, Exception)]
        replies = self.client.request_many([(observations[i].stream, encoded[i]) for i in sendable])
        results: list[Any] = list(encoded)
        for i, reply in zip(sendable, replies):
            results[i] = reply if isinstance(reply, Exception) else _outcome(self._decode, reply, observations[i])
        return results

    def _encode(self, observation: Observation) -> Any:
        try:
            return self.encode(observation)
        except InfrastructureError:
            raise
        except Exception as exc:  # our processing failed on this observation: not the model's behaviour
            raise ClientError(
                f"{type(self).__name__}.encode could not make the request: {type(exc).__name__}: {one_line(str(exc))}"
            ) from exc

    def _decode(self, reply: Any, observation: Observation) -> np.ndarray:
        try:
            return self.decode(reply, observation)
        except (InfrastructureError, PolicyError):
            raise
        except Exception as exc:  # the reply is not what this client expects: not the model's behaviour
            raise ClientError(
                f"could not read the reply of {self.client.url}: {type(exc).__name__}: {one_line(str(exc))}"
            ) from exc

    def close(self) -> None:
        self.client.close()


def _outcome(function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)``, or the exception it raised (a failure that belongs to one episode)."""
    try:
        return function(*args)
    except Exception as exc:
        return exc


def _describe(exc: OSError, timeout: float) -> str:
    if isinstance(exc, TimeoutError):
        return f"no answer within {timeout:g} s"
    if isinstance(exc, ConnectionRefusedError):
        return "connection refused"
    return one_line(f"{type(exc).__name__}: {exc}")
