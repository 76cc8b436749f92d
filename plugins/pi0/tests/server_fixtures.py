"""Policy servers as real processes on 127.0.0.1, for tests: ours or openpi's own, both in the model environment.

``start_server(kind, checkpoint, env, **options) -> (url, process)`` (a session fixture) starts
``python -m conflictbench_pi0 serve`` (``kind="ours"``) or ``tests/openpi_host.py`` (``kind="openpi"``:
openpi-server's ``WebsocketPolicyServer`` around the same backend) on a free port, waits for
``/healthz`` and stops every server it started when the session ends. A server that dies or does not
answer in time fails the test with the tail of its output.

Also the client side of the server tests: a valid ``observation``, ``open_connection`` (closed after
each test by the autouse fixture ``close_connections``, imported by each test module), ``ask``,
``expect_error`` (openpi's error frame and close code 1011) and ``healthz``.
"""

from __future__ import annotations

import contextlib
import os
import urllib.request
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np
import pytest
from tiny_fixtures import MODEL_PYTHON, PLUGIN_ROOT, needs_model_env  # noqa: F401 (re-exported to the server tests)
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from conflictbench import ServerProcess, free_port
from conflictbench_pi0.checkpoints import POLICY_TYPES, checkpoint_type
from conflictbench_pi0.protocol import IMAGE, NOISE_SEED, PROMPT, STATE, WRIST_IMAGE, packb, unpackb

OPENPI_HOST = Path(__file__).resolve().parent / "openpi_host.py"
SERVER_KINDS = ("ours", "openpi")
#: Loading torch and a tiny model takes 10-20 s alone; a busy 2-core machine can take several times that.
STARTUP_TIMEOUT_S = 240.0


def policy_of(checkpoint: Path) -> str:
    """Our policy name (pi0, pi05, pi0-fast) for the LeRobot type in ``checkpoint``'s config."""
    kind = checkpoint_type(checkpoint)
    return next(name for name, lerobot_type in POLICY_TYPES.items() if lerobot_type == kind)


def server_argv(kind: str, checkpoint: Path, port: int, max_batch: int = 4, threads: int = 1) -> list[str]:
    if kind == "ours":
        return [
            str(MODEL_PYTHON), "-m", "conflictbench_serving", policy_of(checkpoint),
            "--checkpoint", str(checkpoint), "--host", "127.0.0.1", "--port", str(port),
            "--max-batch", str(max_batch), "--threads", str(threads),
        ]  # fmt: skip
    if kind == "openpi":
        return [
            str(MODEL_PYTHON), str(OPENPI_HOST), "--checkpoint", str(checkpoint), "--host", "127.0.0.1",
            "--port", str(port), "--threads", str(threads),
        ]  # fmt: skip
    raise ValueError(f"kind must be one of {SERVER_KINDS}, got {kind!r}")


def model_process_env(env: Mapping[str, str]) -> dict[str, str]:
    """This process's environment plus ``env`` (the tiny checkpoints' variables), the plugin importable, one
    CPU thread."""
    defaults = {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16", "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    merged = {**os.environ, **defaults, **env}
    paths = [str(PLUGIN_ROOT), *filter(None, [merged.get("PYTHONPATH", "")])]
    merged["PYTHONPATH"] = os.pathsep.join(paths)
    return merged


def launch_server(
    kind: str,
    checkpoint: Path,
    env: Mapping[str, str],
    *,
    max_batch: int = 4,
    threads: int = 1,
    startup_timeout_s: float = STARTUP_TIMEOUT_S,
) -> tuple[str, ServerProcess]:
    """A started, answering server of ``kind`` for ``checkpoint``; the caller stops it."""
    port = free_port()
    process = ServerProcess(
        server_argv(kind, checkpoint, port, max_batch, threads),
        name=f"pi0-{kind}",
        health_url=f"http://127.0.0.1:{port}/healthz",
        env=model_process_env(env),
        startup_timeout_s=startup_timeout_s,
    )
    try:
        process.start()
    except Exception as error:
        pytest.fail(f"the {kind} server for {checkpoint} did not start: {error}\n{process.log_tail(30)}", pytrace=False)
    return f"ws://127.0.0.1:{port}", process


@pytest.fixture(scope="session")
def start_server() -> Iterator:
    """``start_server(kind, checkpoint, env, **options) -> (url, process)``; all are stopped at the end."""
    started: list[ServerProcess] = []

    def start(kind: str, checkpoint: Path, env: Mapping[str, str], **options) -> tuple[str, ServerProcess]:
        url, process = launch_server(kind, checkpoint, env, **options)
        started.append(process)
        return url, process

    yield start
    for process in started:
        process.stop()


# Client side of the tests: websockets' sync client and the shared codec, as a client would use them.

#: Limit for one frame or connection in tests (a tiny model answers in about 0.1 s).
TIMEOUT_S = 60.0


def observation(seed: int = 0, prompt: str = "put the bowl on the plate", noise_seed: int | None = 7) -> dict:
    """A valid openpi LIBERO request whose images and state follow from ``seed``."""
    rng = np.random.default_rng(seed)
    request = {
        IMAGE: rng.integers(0, 256, (224, 224, 3), dtype=np.uint8),
        WRIST_IMAGE: rng.integers(0, 256, (224, 224, 3), dtype=np.uint8),
        STATE: rng.uniform(-1, 1, 8),
        PROMPT: prompt,
    }
    if noise_seed is not None:
        request[NOISE_SEED] = noise_seed
    return request


open_connections = contextlib.ExitStack()


@pytest.fixture(autouse=True)
def close_connections() -> Iterator[None]:
    """Every connection a test opened is closed when it ends."""
    with open_connections:
        yield


def open_connection(url: str) -> tuple[ClientConnection, dict]:
    """A connection (closed after the test) and the metadata the server sent first."""
    connection = open_connections.enter_context(connect(url, compression=None, max_size=None, open_timeout=TIMEOUT_S))
    first = connection.recv(timeout=TIMEOUT_S)
    assert isinstance(first, bytes), f"the first frame must be binary metadata, got {first!r}"
    return connection, unpackb(first)


def ask(connection: ClientConnection, request: dict) -> dict:
    connection.send(packb(request))
    reply = connection.recv(timeout=TIMEOUT_S)
    assert isinstance(reply, bytes), f"expected a reply, got the error: {reply}"
    return unpackb(reply)


def expect_error(connection: ClientConnection, fragment: str) -> str:
    """The error text frame (containing ``fragment``), then close code 1011, as openpi's server does."""
    text = connection.recv(timeout=TIMEOUT_S)
    assert isinstance(text, str) and fragment in text, text
    with pytest.raises(ConnectionClosed) as closed:
        connection.recv(timeout=TIMEOUT_S)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1011
    return text


def healthz(url: str) -> tuple[int, bytes]:
    with urllib.request.urlopen(url.replace("ws://", "http://") + "/healthz", timeout=TIMEOUT_S) as reply:
        return reply.status, reply.read()


def malformed(**changes) -> dict:
    """A valid request with ``changes`` (image, wrist, state, prompt, seed: a new value, or None to drop it)."""
    request = observation(5)
    for key, value in changes.items():
        key = {"image": IMAGE, "wrist": WRIST_IMAGE, "state": STATE, "prompt": PROMPT, "seed": NOISE_SEED}[key]
        if value is None:
            del request[key]
        else:
            request[key] = value
    return request
