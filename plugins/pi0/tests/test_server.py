"""The batching openpi-protocol server, its CLI, and openpi's own server as the counterpart.

Three layers, each over real sockets on 127.0.0.1:

- the server's queueing and batching, in this process, around a stand-in model whose actions are a pure
  function of the request and whose calls can be held, so which requests share a batch is decided by the
  test and not by timing (the only stand-in here: the model is the boundary under test);
- the CLI's user errors (subprocesses; no model needed);
- end to end (``model_env``): ``conflictbench-pi0 serve`` and ``tests/openpi_host.py`` in the model
  environment with a tiny random-weight pi0.5.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from server_fixtures import STARTUP_TIMEOUT_S, launch_server, model_process_env, needs_model_env, server_argv
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from conflictbench_pi0.protocol import ACTIONS, IMAGE, NOISE_SEED, PROMPT, STATE, WRIST_IMAGE, packb, unpackb
from conflictbench_pi0.server import BatchingPolicyServer, InvalidRequest, validate_request

TIMEOUT_S = 60.0
PLUGIN_ROOT = Path(__file__).resolve().parents[1]


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


_open_connections = contextlib.ExitStack()


@pytest.fixture(autouse=True)
def _close_connections() -> Iterator[None]:
    """Every connection a test opened is closed when it ends."""
    with _open_connections:
        yield


def open_connection(url: str) -> tuple[ClientConnection, dict]:
    """A connection (closed after the test) and the metadata the server sent first."""
    connection = _open_connections.enter_context(connect(url, compression=None, max_size=None, open_timeout=TIMEOUT_S))
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


# ----------------------------------------------------------------------------------------------------
# The server around a stand-in model


def stand_in_actions(request: dict) -> np.ndarray:
    """The stand-in's chunk: different for every image, state, prompt and seed."""
    base = float(request[IMAGE].mean()) + float(request[WRIST_IMAGE].mean()) / 7 + float(np.sum(request[STATE]))
    base += len(request[PROMPT]) + int(request.get(NOISE_SEED, 0))
    return (base + np.arange(70, dtype=np.float32).reshape(10, 7)).astype(np.float32)


class StandInModel:
    """``PiBackend``'s interface; each call can be held until ``release`` and records its batch size."""

    metadata = {"policy_type": "pi05", "action_dim": 7, "action_horizon": 10}

    def __init__(self, held: bool = False) -> None:
        self.released = threading.Event()
        if not held:
            self.released.set()
        self.entered = threading.Semaphore(0)
        self.batch_sizes: list[int] = []
        self._lock = threading.Lock()
        self._running = 0
        self.most_running = 0

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]:
        with self._lock:
            self._running += 1
            self.most_running = max(self.most_running, self._running)
        self.entered.release()
        try:
            assert self.released.wait(TIMEOUT_S)
            time.sleep(0.01)  # a call long enough for an overlapping one to be seen
            self.batch_sizes.append(len(requests))
            if any(request[PROMPT] == "fail" for request in requests):
                raise RuntimeError("the stand-in model failed")
            return [stand_in_actions(request) for request in requests]
        finally:
            with self._lock:
                self._running -= 1


@contextlib.contextmanager
def serving(model: StandInModel, max_batch: int = 32) -> Iterator[tuple[str, BatchingPolicyServer]]:
    """The server on a free port, its event loop in a thread; stopped (and checked stopped) at the end."""
    server = BatchingPolicyServer(model, max_batch)
    bound, ready = {}, threading.Event()

    async def main() -> None:
        bound["loop"], bound["stop"] = asyncio.get_running_loop(), asyncio.Event()

        def on_ready(host: str, port: int) -> None:
            bound["port"] = port
            ready.set()

        await server.run("127.0.0.1", 0, bound["stop"], on_ready=on_ready)

    thread = threading.Thread(target=asyncio.run, args=(main(),), daemon=True)
    thread.start()
    assert ready.wait(TIMEOUT_S), "the server did not bind"
    try:
        yield f"ws://127.0.0.1:{bound['port']}", server
    finally:
        bound["loop"].call_soon_threadsafe(bound["stop"].set)
        thread.join(TIMEOUT_S)
        assert not thread.is_alive(), "the server did not stop"


def wait_until(condition, what: str) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting until {what}"
        time.sleep(0.005)


def hold_model_with_one_request(url: str, model: StandInModel) -> ClientConnection:
    """A connection whose request the model is busy with (held) when this returns."""
    connection, _ = open_connection(url)
    connection.send(packb(observation(100)))
    assert model.entered.acquire(timeout=TIMEOUT_S)
    return connection


def test_metadata_first_healthz_and_reply():
    model = StandInModel()
    with serving(model) as (url, _):
        assert healthz(url) == (200, b"OK\n")
        connection, metadata = open_connection(url)
        assert metadata == StandInModel.metadata
        request = observation(1)
        reply = ask(connection, request)
        np.testing.assert_array_equal(reply[ACTIONS], stand_in_actions(request))
        assert reply[ACTIONS].dtype == np.float32
        assert reply["server_timing"]["batch_size"] == 1 and reply["server_timing"]["infer_ms"] > 0
        second = ask(connection, observation(2))
        assert second["server_timing"]["prev_total_ms"] > 0  # as openpi's server reports it


@pytest.mark.parametrize("max_batch, expected_batches", [(32, [1, 3]), (2, [1, 2, 1])])
def test_requests_queued_while_the_model_is_busy_share_one_batch(max_batch, expected_batches):
    model = StandInModel(held=True)
    with serving(model, max_batch) as (url, server):
        first = hold_model_with_one_request(url, model)
        connections = [open_connection(url)[0] for _ in range(3)]
        requests = [observation(seed, noise_seed=seed) for seed in range(3)]
        for connection, request in zip(connections, requests, strict=True):
            connection.send(packb(request))
        wait_until(lambda: server.queued == 3, "three requests are queued")
        model.released.set()
        assert unpackb(first.recv(timeout=TIMEOUT_S))["server_timing"]["batch_size"] == 1
        for connection, request in zip(connections, requests, strict=True):
            reply = unpackb(connection.recv(timeout=TIMEOUT_S))
            np.testing.assert_array_equal(reply[ACTIONS], stand_in_actions(request))  # each gets its own chunk
        assert model.batch_sizes == expected_batches
        assert model.most_running == 1  # model calls never overlap


def test_concurrent_clients_never_overlap_model_calls():
    model = StandInModel()
    with serving(model) as (url, _):

        def client(seed: int) -> None:
            connection, _ = open_connection(url)
            for step in range(5):
                request = observation(seed, noise_seed=step)
                np.testing.assert_array_equal(ask(connection, request)[ACTIONS], stand_in_actions(request))

        with ThreadPoolExecutor(4) as pool:
            list(pool.map(client, range(4)))
    assert sum(model.batch_sizes) == 20 and model.most_running == 1


def test_a_failing_model_call_fails_its_whole_batch_and_nothing_else():
    model = StandInModel(held=True)
    with serving(model) as (url, server):
        first = hold_model_with_one_request(url, model)
        failing, _ = open_connection(url)
        neighbour, _ = open_connection(url)
        failing.send(packb(observation(1, prompt="fail")))
        neighbour.send(packb(observation(2)))
        wait_until(lambda: server.queued == 2, "both requests are queued")
        model.released.set()
        assert first.recv(timeout=TIMEOUT_S)  # the batch before is answered
        for connection in (failing, neighbour):
            text = expect_error(connection, "RuntimeError: the stand-in model failed")
            assert text.startswith("Traceback")
        later, _ = open_connection(url)
        request = observation(3)
        np.testing.assert_array_equal(ask(later, request)[ACTIONS], stand_in_actions(request))
        reused = ask(first, request)  # the earlier connection still works too
        np.testing.assert_array_equal(reused[ACTIONS], stand_in_actions(request))


def malformed(**changes) -> dict:
    request = observation(5)
    for key, value in changes.items():
        key = {"image": IMAGE, "wrist": WRIST_IMAGE, "state": STATE, "prompt": PROMPT, "seed": NOISE_SEED}[key]
        if value is None:
            del request[key]
        else:
            request[key] = value
    return request


MALFORMED = {
    "image of 256 px": (malformed(image=np.zeros((256, 256, 3), np.uint8)), "'observation/image' must be a uint8"),
    "float image": (malformed(wrist=np.zeros((224, 224, 3), np.float32)), "'observation/wrist_image' must be"),
    "image as a list": (malformed(image=[1, 2, 3]), "got list"),
    "no wrist image": (malformed(wrist=None), "missing 'observation/wrist_image'"),
    "state of 7": (malformed(state=np.zeros(7)), "'observation/state' must be 8 finite numbers"),
    "state with NaN": (malformed(state=np.full(8, np.nan)), "'observation/state' must be 8"),
    "state of text": (malformed(state="12345678"), "'observation/state' must be 8"),
    "prompt of bytes": (malformed(prompt=b"pick"), "'prompt' must be a string"),
    "negative seed": (malformed(seed=-1), "'conflictbench/noise_seed' must be an int"),
    "float seed": (malformed(seed=1.5), "'conflictbench/noise_seed' must be an int"),
    "boolean seed": (malformed(seed=True), "'conflictbench/noise_seed' must be an int"),
}


@pytest.mark.parametrize("request_, fragment", MALFORMED.values(), ids=MALFORMED.keys())
def test_validate_request_says_what_is_wrong(request_, fragment):
    with pytest.raises(InvalidRequest) as error:
        validate_request(request_)
    assert fragment in str(error.value)


def test_validate_request_accepts_lists_and_numpy_seeds():
    request = malformed(state=[0.0] * 8, seed=np.int64(3))
    assert validate_request(request) is request
    assert validate_request(malformed(seed=None)) is not None  # the seed is optional


RAW_FRAMES = {
    "text frame": ("hello", "must be a binary frame"),
    "not msgpack": (b"\xc1", "not an openpi msgpack frame"),
    "a list": (packb([1, 2]), "a request must be a map, got list"),
    "bad image": (packb(MALFORMED["image of 256 px"][0]), "must be a uint8 array of shape (224, 224, 3)"),
}


@pytest.mark.parametrize("frame, fragment", RAW_FRAMES.values(), ids=RAW_FRAMES.keys())
def test_a_malformed_request_closes_only_its_own_connection(frame, fragment):
    model = StandInModel()
    with serving(model) as (url, _):
        bystander, _ = open_connection(url)
        offender, _ = open_connection(url)
        offender.send(frame)
        assert expect_error(offender, fragment).startswith("invalid request: ")
        request = observation(9)
        np.testing.assert_array_equal(ask(bystander, request)[ACTIONS], stand_in_actions(request))
    assert model.batch_sizes == [1]  # the malformed request never reached the model


# ----------------------------------------------------------------------------------------------------
# The CLI's user errors: one line on stderr, exit 2, before any model import


def run_cli(*args: str, python: str = sys.executable) -> subprocess.CompletedProcess:
    return subprocess.run(
        [python, "-m", "conflictbench_pi0", *args], capture_output=True, text=True, timeout=120, cwd=PLUGIN_ROOT
    )


def fake_checkpoint(folder: Path, kind: str | None = "pi05", weights: bool = True) -> Path:
    folder.mkdir(parents=True)
    if kind is not None:
        (folder / "config.json").write_text(json.dumps({"type": kind}))
    if weights:
        (folder / "model.safetensors").write_bytes(b"")
    return folder


@pytest.mark.parametrize(
    "policy, kind, weights, fragment",
    [
        ("pi05", "missing", True, "no checkpoint folder at"),
        ("pi05", None, True, "is not a LeRobot checkpoint (no config.json)"),
        ("pi05", "act", True, "holds a act policy, not a π one"),
        ("pi05", "pi05", False, "has no model.safetensors"),
        ("pi0", "pi05", True, "is a pi05 checkpoint: use --policy pi05, not pi0"),
        ("pi0-fast", "pi0", True, "is a pi0 checkpoint: use --policy pi0, not pi0-fast"),
    ],
)
def test_cli_checkpoint_errors_are_one_line_and_exit_2(tmp_path, policy, kind, weights, fragment):
    folder = tmp_path / "missing" if kind == "missing" else fake_checkpoint(tmp_path / "ckpt", kind, weights)
    done = run_cli("serve", "--policy", policy, "--checkpoint", str(folder))
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("conflictbench-pi0: ") and fragment in done.stderr
    assert done.stdout == ""


def test_cli_without_the_model_stack_says_which_python_to_use(tmp_path):
    """The simulator's environment has no torch: a valid-looking checkpoint gets that far, and no further."""
    done = run_cli("serve", "--policy", "pi05", "--checkpoint", str(fake_checkpoint(tmp_path / "ckpt")))
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "run this with the model environment's python" in done.stderr


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["serve", "--policy", "pi5", "--checkpoint", "x"], "invalid choice: 'pi5'"),
        (["serve", "--checkpoint", "x"], "the following arguments are required: --policy"),
        (["serve", "--policy", "pi05", "--checkpoint", "x", "--max-batch", "0"], "--max-batch must be at least 1"),
        (["serve", "--policy", "pi05", "--checkpoint", "x", "--threads", "0"], "--threads must be at least 1"),
        ([], "the following arguments are required: command"),
    ],
)
def test_cli_usage_errors_are_one_line_and_exit_2(args, fragment):
    done = run_cli(*args)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and fragment in done.stderr


# ----------------------------------------------------------------------------------------------------
# End to end: the tiny pi0.5 behind our server and behind openpi's, in the model environment


@pytest.fixture(scope="module")
def tiny_pi05(tiny_checkpoints) -> Path:
    return tiny_checkpoints["pi05"]


@pytest.fixture(scope="module")
def ours(start_server, tiny_pi05, tiny_env) -> str:
    return start_server("ours", tiny_pi05, tiny_env)[0]


@pytest.fixture(scope="module")
def theirs(start_server, tiny_pi05, tiny_env) -> str:
    return start_server("openpi", tiny_pi05, tiny_env)[0]


@pytest.mark.model_env
@needs_model_env
@pytest.mark.parametrize("kind", ["ours", "theirs"])
def test_e2e_metadata_healthz_and_reply_shape(kind, request):
    url = request.getfixturevalue(kind)
    assert healthz(url) == (200, b"OK\n")
    connection, metadata = open_connection(url)
    assert metadata["policy_type"] == "pi05" and metadata["action_dim"] == 7
    reply = ask(connection, observation(1))
    assert reply[ACTIONS].dtype == np.float32
    assert reply[ACTIONS].shape == (metadata["action_horizon"], 7)
    assert np.all(np.isfinite(reply[ACTIONS]))
    assert reply["server_timing"]["infer_ms"] > 0
    if kind == "ours":
        assert reply["server_timing"]["batch_size"] == 1


@pytest.mark.model_env
@needs_model_env
def test_e2e_malformed_request_leaves_other_connections_working(ours):
    bystander, _ = open_connection(ours)
    before = ask(bystander, observation(2))
    offender, _ = open_connection(ours)
    offender.send(packb(malformed(state=np.zeros(7))))
    expect_error(offender, "invalid request: 'observation/state' must be 8 finite numbers")
    after = ask(bystander, observation(2))
    np.testing.assert_array_equal(after[ACTIONS], before[ACTIONS])


@pytest.mark.model_env
@needs_model_env
def test_e2e_concurrent_requests_share_a_batch_and_match_single_requests(ours):
    """Two requests arriving while the model is busy are answered by one forward pass, each with its own actions.

    A third connection's request keeps the model busy (a tiny-model call takes about 100 ms) while the two
    arrive, so they queue together; two requests sent at the same instant to an idle server would usually
    be answered one by one, since the first starts the model as soon as it arrives.
    """
    requests = [observation(10, "open the drawer", noise_seed=11), observation(20, "close the drawer", noise_seed=22)]
    alone_connection, _ = open_connection(ours)
    alone = [ask(alone_connection, request) for request in requests]
    assert all(reply["server_timing"]["batch_size"] == 1 for reply in alone)
    assert not np.allclose(alone[0][ACTIONS], alone[1][ACTIONS])
    busy, _ = open_connection(ours)
    connections = [open_connection(ours)[0] for _ in requests]
    start = threading.Barrier(len(requests))

    def send_together(index: int) -> dict:
        start.wait(TIMEOUT_S)
        return ask(connections[index], requests[index])

    seen = []
    with ThreadPoolExecutor(len(requests)) as pool:
        for _ in range(5):  # a loaded machine may still let the busy request start late
            busy.send(packb(observation(30)))
            time.sleep(0.03)
            together = list(pool.map(send_together, range(len(requests))))
            assert isinstance(busy.recv(timeout=TIMEOUT_S), bytes)
            timings = [reply["server_timing"] for reply in together]
            seen.append([timing["batch_size"] for timing in timings])
            if seen[-1] == [2, 2] and timings[0]["infer_ms"] == timings[1]["infer_ms"]:  # the same call
                break
        else:
            pytest.fail(f"the two requests never shared a batch of 2 (batch sizes seen: {seen})")
    for batched, single in zip(together, alone, strict=True):
        # Measured on the tiny pi0.5: identical; the tolerance allows for other kernels' batched reductions.
        np.testing.assert_allclose(batched[ACTIONS], single[ACTIONS], rtol=1e-5, atol=1e-5)


@pytest.mark.model_env
@needs_model_env
def test_e2e_our_server_and_openpis_give_the_same_actions(ours, theirs):
    for seed in (0, 1):
        request = observation(30 + seed, noise_seed=seed)
        ours_connection, _ = open_connection(ours)
        theirs_connection, _ = open_connection(theirs)
        np.testing.assert_array_equal(ask(ours_connection, request)[ACTIONS], ask(theirs_connection, request)[ACTIONS])


@pytest.mark.model_env
@needs_model_env
@pytest.mark.parametrize("policy, horizon", [("pi0", 50), ("pi0-fast", 10)])
def test_e2e_pi0_and_pi0_fast_are_served_like_openpi_serves_them(tiny_checkpoints, tiny_env, policy, horizon):
    servers = [launch_server(kind, tiny_checkpoints[policy], tiny_env) for kind in ("ours", "openpi")]
    try:
        replies = []
        for url, _ in servers:
            connection, metadata = open_connection(url)
            assert metadata["action_horizon"] == horizon
            replies.append([ask(connection, observation(40 + seed, noise_seed=seed))[ACTIONS] for seed in (0, 1)])
        (ours_first, ours_second), (theirs_first, theirs_second) = replies
        assert ours_first.shape == (horizon, 7) and not np.array_equal(ours_first, ours_second)
        np.testing.assert_array_equal(ours_first, theirs_first)
        np.testing.assert_array_equal(ours_second, theirs_second)
    finally:
        for _, process in servers:
            process.stop()


@pytest.mark.model_env
@needs_model_env
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_e2e_signals_stop_the_server_cleanly(tiny_pi05, tiny_env, signum):
    url, server = launch_server("ours", tiny_pi05, tiny_env)
    try:
        connection, _ = open_connection(url)
        ask(connection, observation(3))
        process = server.process
        process.send_signal(signum)
        assert process.wait(TIMEOUT_S) == 0
        with pytest.raises(ConnectionClosed):
            connection.recv(timeout=TIMEOUT_S)
        log = server.log_path.read_text()
        assert "Traceback" not in log
        assert f"conflictbench-pi0: serving pi05 from {tiny_pi05} on ws://127.0.0.1:" in log
    finally:
        server.stop()


@pytest.mark.model_env
@needs_model_env
def test_e2e_a_port_in_use_is_a_user_error(tiny_pi05, tiny_env):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [*server_argv("ours", tiny_pi05, port)], env=model_process_env(tiny_env), capture_output=True, text=True,
            timeout=STARTUP_TIMEOUT_S,
        )  # fmt: skip
    assert done.returncode == 2
    assert done.stderr.splitlines()[-1].startswith(f"conflictbench-pi0: cannot listen on 127.0.0.1:{port}: ")
