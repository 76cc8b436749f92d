"""The batching server and its CLI's user errors, without a model.

The server's queueing and batching run in this process, over real sockets on 127.0.0.1, around a stand-in
model whose actions are a pure function of the request and whose calls can be held, so which requests share
a batch is decided by the test and not by timing (the model is the boundary under test; end to end with a
real tiny checkpoint: ``test_pi0_server_e2e.py``). The CLI's user errors run as subprocesses.
"""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from server_fixtures import (
    PLUGIN_ROOT,
    TIMEOUT_S,
    ask,
    close_connections,  # noqa: F401 (autouse)
    expect_error,
    healthz,
    malformed,
    observation,
    open_connection,
)
from websockets.sync.client import ClientConnection

from conflictbench.testing.plugin_tests import check_serve_refuses, lerobot_folder, serve_command
from conflictbench_pi0.protocol import (
    ACTIONS,
    IMAGE,
    NOISE_SEED,
    PROMPT,
    STATE,
    WRIST_IMAGE,
    InvalidRequest,
    packb,
    unpackb,
    validate_request,
)
from conflictbench_pi0.server import BatchingPolicyServer


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
def serving(
    model: StandInModel, max_batch: int = 32, fixed_shape: bool = False
) -> Iterator[tuple[str, BatchingPolicyServer]]:
    """The server on a free port, its event loop in a thread; stopped (and checked stopped) at the end."""
    server = BatchingPolicyServer(model, max_batch, fixed_shape)
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
        assert metadata == {**StandInModel.metadata, "max_batch": 32, "fixed_shape": False}
        request = observation(1)
        reply = ask(connection, request)
        np.testing.assert_array_equal(reply[ACTIONS], stand_in_actions(request))
        assert reply[ACTIONS].dtype == np.float32
        assert reply["server_timing"]["batch_size"] == 1 and reply["server_timing"]["infer_ms"] > 0
        second = ask(connection, observation(2))
        assert second["server_timing"]["prev_total_ms"] > 0  # as openpi's server reports it


@pytest.mark.parametrize(
    "max_batch, fixed_shape, queued, model_calls, served_together",
    [
        (32, False, 3, [1, 3], [3, 3, 3]),
        (2, False, 3, [1, 2, 1], [2, 2, 1]),
        (4, True, 2, [4, 4], [2, 2]),  # every call padded to four rows; replies count the requests served
    ],
)
def test_requests_queued_while_the_model_is_busy_share_one_call(
    max_batch, fixed_shape, queued, model_calls, served_together
):
    model = StandInModel(held=True)
    with serving(model, max_batch, fixed_shape) as (url, server):
        first = hold_model_with_one_request(url, model)
        connections = [open_connection(url)[0] for _ in range(queued)]
        requests = [observation(seed, noise_seed=seed) for seed in range(queued)]
        for connection, request in zip(connections, requests, strict=True):
            connection.send(packb(request))
        wait_until(lambda: server.queued == queued, f"{queued} requests are queued")
        model.released.set()
        assert unpackb(first.recv(timeout=TIMEOUT_S))["server_timing"]["batch_size"] == 1
        replies = [unpackb(connection.recv(timeout=TIMEOUT_S)) for connection in connections]
        for reply, request in zip(replies, requests, strict=True):
            np.testing.assert_array_equal(reply[ACTIONS], stand_in_actions(request))  # each gets its own chunk
        # which connection's request reached the queue first is the event loop's order, not the send order
        assert sorted(reply["server_timing"]["batch_size"] for reply in replies) == sorted(served_together)
        assert model.batch_sizes == model_calls
        assert model.most_running == 1  # model calls never overlap
        _, metadata = open_connection(url)
        assert (metadata["max_batch"], metadata["fixed_shape"]) == (max_batch, fixed_shape)


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
            assert text == "RuntimeError: the stand-in model failed"  # one line: our internals stay in our log
        later, _ = open_connection(url)
        request = observation(3)
        np.testing.assert_array_equal(ask(later, request)[ACTIONS], stand_in_actions(request))
        reused = ask(first, request)  # the earlier connection still works too
        np.testing.assert_array_equal(reused[ACTIONS], stand_in_actions(request))


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
# conflictbench-serve's user errors: one line on stderr, exit 2, before any model import (in this Python, with the
# server half's entry point; the simulator's environment has no torch)


def fake_checkpoint(folder: Path, kind: str | None = "pi05", weights: bool = True) -> Path:
    return lerobot_folder(folder, kind, ("model.safetensors",) if weights else ())


@pytest.mark.parametrize(
    "policy, kind, weights, fragment",
    [
        ("pi05", "missing", True, "no checkpoint folder at"),
        ("pi05", None, True, "is not a LeRobot checkpoint (no config.json)"),
        ("pi05", "act", True, "holds a act policy, not a π one"),
        ("pi05", "pi05", False, "has no model.safetensors"),
        ("pi0", "pi05", True, "is a pi05 checkpoint: use conflictbench-serve pi05, not conflictbench-serve pi0"),
        ("pi0-fast", "pi0", True, "is a pi0 checkpoint: use conflictbench-serve pi0, not conflictbench-serve pi0-fast"),
    ],
)
def test_serve_checkpoint_errors_are_one_line_and_exit_2(tmp_path, policy, kind, weights, fragment):
    folder = tmp_path / "missing" if kind == "missing" else fake_checkpoint(tmp_path / "ckpt", kind, weights)
    check_serve_refuses(PLUGIN_ROOT, tmp_path, policy, folder, fragment)


def test_serve_without_the_model_stack_says_which_python_to_use(tmp_path):
    """The simulator's environment has no torch: a valid-looking checkpoint gets that far, and no further."""
    folder = fake_checkpoint(tmp_path / "ckpt")
    check_serve_refuses(PLUGIN_ROOT, tmp_path, "pi05", folder, "run this with the model environment's python")


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["pi5", "--checkpoint", "x"], "no installed plugin serves 'pi5' (installed: pi0, pi0-fast, pi05"),
        (["--checkpoint", "x"], "the following arguments are required: POLICY"),
        (["pi05", "--checkpoint", "x", "--max-batch", "0"], "--max-batch must be at least 1"),
        (["pi05", "--checkpoint", "x", "--threads", "0"], "--threads must be at least 1"),
    ],
)
def test_serve_usage_errors_are_one_line_and_exit_2(tmp_path, args, fragment):
    done = serve_command(PLUGIN_ROOT, tmp_path, *args)
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and fragment in done.stderr


def test_serve_beside_the_simulator_says_the_server_half_is_in_the_model_environment():
    """The client half declares nothing for conflictbench-serve (this Python has no server half installed)."""
    done = subprocess.run([sys.executable, "-m", "conflictbench_serving", "pi05", "--checkpoint", "x"],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and done.stderr.count("\n") == 1
    assert "(installed: none; a model plugin's server half is in its model environment" in done.stderr
