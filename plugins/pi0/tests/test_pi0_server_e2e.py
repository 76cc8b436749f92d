"""End to end, in the model environment: a tiny random-weight checkpoint behind ``conflictbench-serve pi05``
and behind openpi's own ``openpi-server`` (``tests/openpi_host.py``), real processes on 127.0.0.1."""

from __future__ import annotations

import signal
import socket
import subprocess
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from server_fixtures import (
    STARTUP_TIMEOUT_S,
    TIMEOUT_S,
    ask,
    close_connections,  # noqa: F401 (autouse)
    expect_error,
    healthz,
    launch_server,
    malformed,
    model_process_env,
    needs_model_env,
    observation,
    open_connection,
    server_argv,
)
from websockets.exceptions import ConnectionClosed

from conflictbench_pi0.protocol import ACTIONS, packb


@pytest.fixture(scope="module")
def tiny_pi05(tiny_checkpoints) -> Path:
    return tiny_checkpoints["pi05"]


@pytest.fixture(scope="module")
def ours(start_server, tiny_pi05, tiny_env) -> str:
    return start_server("ours", tiny_pi05, tiny_env)[0]


@pytest.fixture(scope="module")
def theirs(start_server, tiny_pi05, tiny_env) -> str:
    return start_server("openpi", tiny_pi05, tiny_env)[0]


@pytest.fixture(scope="module")
def ours_one_row(start_server, tiny_pi05, tiny_env) -> str:
    """Ours with forward passes of one row: the shape of openpi's calls, so the rounding is the same too."""
    return start_server("ours", tiny_pi05, tiny_env, max_batch=1)[0]


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


@needs_model_env
def test_e2e_malformed_request_leaves_other_connections_working(ours):
    bystander, _ = open_connection(ours)
    before = ask(bystander, observation(2))
    offender, _ = open_connection(ours)
    offender.send(packb(malformed(state=np.zeros(7))))
    expect_error(offender, "invalid request: 'observation/state' must be 8 finite numbers")
    after = ask(bystander, observation(2))
    np.testing.assert_array_equal(after[ACTIONS], before[ACTIONS])


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
        # Every call has the same shape (max_batch rows, padded), so company and position change nothing.
        np.testing.assert_array_equal(batched[ACTIONS], single[ACTIONS])


@needs_model_env
def test_e2e_our_server_and_openpis_give_the_same_actions(ours, ours_one_row, theirs):
    for seed in (0, 1):
        request = observation(30 + seed, noise_seed=seed)
        replies = [ask(open_connection(url)[0], request)[ACTIONS] for url in (ours_one_row, theirs, ours)]
        np.testing.assert_array_equal(replies[0], replies[1])
        # four rows per call round differently than one, in the last float32 bits only
        np.testing.assert_allclose(replies[2], replies[1], rtol=1e-5, atol=1e-6)


@needs_model_env
@pytest.mark.parametrize("policy, horizon", [("pi0", 50), ("pi0-fast", 10)])
def test_e2e_pi0_and_pi0_fast_are_served_like_openpi_serves_them(tiny_checkpoints, tiny_env, policy, horizon):
    servers = [launch_server(kind, tiny_checkpoints[policy], tiny_env, max_batch=1) for kind in ("ours", "openpi")]
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
        assert f"conflictbench-serve: serving pi05 from {tiny_pi05} on ws://127.0.0.1:" in log
    finally:
        server.stop()


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
    assert done.stderr.splitlines()[-1].startswith(f"conflictbench-serve: cannot listen on 127.0.0.1:{port}: ")
