"""The shared client for served policies, against a real HTTP server on 127.0.0.1 (tests/policy_server.py).

Each test starts its own server process and stops it at teardown; backoffs are shortened so that
every retry loop here ends within a few seconds.
"""

from __future__ import annotations

import importlib.util
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from policy_server import PolicyServer, served_action
from testing_support import episode_record, wait_until

from conflictbench import InfrastructureError, PolicyClient, ServerUnavailable
from conflictbench.core import (
    INFRASTRUCTURE_ERROR_PREFIX,
    SIMULATOR_ERROR_PREFIX,
    ClientError,
    EpisodeRecord,
    Observation,
)
from conflictbench.report.summary import pair_up
from conflictbench.store import EpisodeStore

PLUGIN_SOURCE = Path(__file__).parent / "plugins" / "conflictbench-served" / "conflictbench_served" / "__init__.py"


def _plugin_module():
    spec = importlib.util.spec_from_file_location("conflictbench_served", PLUGIN_SOURCE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


served = _plugin_module()


def observation(step: int = 0, stream: int = 0, instruction: str = "put the bowl on the plate") -> Observation:
    state = np.array([0.1 * (stream + 1), 0.2, 1.0, 0.0, 0.0, 0.0, 0.04, -0.04])
    return Observation(
        step=step,
        instruction=instruction,
        eef_pos=state[:3],
        eef_quat=np.array([0, 0, 0, 1.0]),
        gripper_qpos=state[6:],
        state=state,
        stream=stream,
    )


def expected(obs: Observation) -> np.ndarray:
    return np.array(served_action(obs.step, obs.state.tolist()))


def policy_for(url: str, **settings) -> served.ServedTestPolicy:
    return served.ServedTestPolicy(served.ServedTestConfig(server=url, **settings))


def free_port() -> int:
    """A port nobody listens on (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def server():
    """server(*options) -> a running PolicyServer, stopped at teardown (also when the test fails)."""
    started: list[PolicyServer] = []

    def _start(*options: str, port: int = 0) -> PolicyServer:
        started.append(PolicyServer(*options, port=port))
        return started[-1]

    yield _start
    for s in started:
        s.stop()


def test_a_served_policy_gets_the_servers_actions(server):
    srv = server()
    policy = policy_for(srv.url)
    try:
        for step in range(3):
            obs = observation(step)
            np.testing.assert_allclose(policy.act(obs), expected(obs))
    finally:
        policy.close()
    stats = srv.stats()
    assert stats["requests"] == 3 and stats["dropped"] == 0


def test_nobody_listening_stops_with_the_url_after_the_configured_retries():
    url = f"http://127.0.0.1:{free_port()}/act"
    client = PolicyClient(url, connect_retries=3, backoff_s=0.05, max_backoff_s=0.1)
    assert client.backoff_delays() == [0.05, 0.1, 0.1]
    start = time.monotonic()
    with pytest.raises(ServerUnavailable) as caught:
        client.open()
    elapsed = time.monotonic() - start
    assert 0.25 <= elapsed < 2.0  # the three waits, and no more
    message = str(caught.value)
    assert url in message and "connection refused" in message and "4 attempt(s)" in message
    assert "\n" not in message and caught.value.exit_code == 3


@pytest.mark.parametrize("scheme", ["http", "tcp"])  # tcp: GR00T's ZeroMQ, whose connect() never fails itself
def test_an_unreachable_server_is_retried_aloud_and_given_up_on_as_quickly_as_any(scheme, capsys):
    if scheme == "tcp":
        pytest.importorskip("zmq")
    from conflictbench.hosting.transport import HttpJsonTransport
    from conflictbench.hosting.zeromq import ZmqTransport

    url = f"{scheme}://127.0.0.1:{free_port()}" + ("/act" if scheme == "http" else "")
    transport = ZmqTransport if scheme == "tcp" else HttpJsonTransport
    client = PolicyClient(url, transport, connect_timeout_s=10, connect_retries=2, backoff_s=0.05)
    start = time.monotonic()
    with pytest.raises(ServerUnavailable, match="connection refused; 3 attempt"):
        client.open()
    assert time.monotonic() - start < 3.0  # the waits between attempts, never a connect timeout per attempt
    said = [line for line in capsys.readouterr().err.splitlines() if url in line]
    assert len(said) == 2 and "attempt 1 of 3" in said[0] and "attempt 2 of 3" in said[1], said


def test_a_server_that_never_accepts_hits_the_connect_timeout():
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(0)
        url = f"http://127.0.0.1:{listener.getsockname()[1]}/act"
        with socket.create_connection(listener.getsockname()):  # fills the backlog: further SYNs go unanswered
            client = PolicyClient(url, connect_timeout_s=0.2, connect_retries=1, backoff_s=0.05)
            start = time.monotonic()
            with pytest.raises(ServerUnavailable, match="no answer within 0.2 s; 2 attempt"):
                client.open()
            assert 0.4 <= time.monotonic() - start < 2.0


def test_a_connection_closed_once_is_reopened_and_the_request_succeeds(server):
    srv = server("--drop-first", "1")
    policy = policy_for(srv.url)
    try:
        obs = observation(step=4)
        np.testing.assert_allclose(policy.act(obs), expected(obs))
    finally:
        policy.close()
    assert srv.stats()["dropped"] == 1 and srv.stats()["requests"] == 2


def test_a_connection_that_breaks_on_every_resend_fails_the_episode_not_the_run(server):
    srv = server("--drop-first", "3")
    policy = policy_for(srv.url, resends=2)
    try:
        with pytest.raises(InfrastructureError, match="broke 3 times on one request"):
            policy.act(observation())
        obs = observation(step=1)  # the server answers again: so does the client
        np.testing.assert_allclose(policy.act(obs), expected(obs))
    finally:
        policy.close()


@pytest.mark.parametrize("form", ["http500", "error-body"])
def test_a_server_error_reply_is_an_infrastructure_error(server, form):
    srv = server("--fail-instruction", "stove", *(["--error-body"] if form == "error-body" else []))
    policy = policy_for(srv.url)
    try:
        with pytest.raises(InfrastructureError, match="out of memory") as caught:
            policy.act(observation(instruction="pick up the stove"))
        assert srv.url in str(caught.value) and ("HTTP 500" in str(caught.value)) == (form == "http500")
        obs = observation(step=2)  # same connection, next episode: fine
        np.testing.assert_allclose(policy.act(obs), expected(obs))
    finally:
        policy.close()
    assert srv.stats()["errors"] == 1 and srv.stats()["requests"] == 2  # an error reply is never resent


def test_a_reply_too_slow_fails_the_episode_and_is_not_resent(server):
    srv = server("--delay", "0.6")
    policy = policy_for(srv.url, request_timeout_s=0.2)
    try:
        with pytest.raises(InfrastructureError, match="no reply from .* within 0.2 s"):
            policy.act(observation())
    finally:
        policy.close()
    # the closed client can send nothing more: once the server has answered all it got, it has seen every try
    assert wait_until(lambda: srv.stats()["in_flight"] == 0, 5)
    assert srv.stats()["requests"] == 1


def test_n_streams_keep_n_requests_in_flight(server):
    srv = server("--delay", "1.0")  # all four must arrive while the first is held (0.4 s was short under load)
    policy = policy_for(srv.url)
    observations = [observation(step=3, stream=s) for s in range(4)]
    try:
        start = time.monotonic()
        actions = policy.act_batch(observations)
        elapsed = time.monotonic() - start
    finally:
        policy.close()
    for obs, action in zip(observations, actions):
        np.testing.assert_allclose(action, expected(obs))
    stats = srv.stats()
    assert stats["max_in_flight"] == 4 and stats["streams"] == [0, 1, 2, 3]
    assert elapsed < 2 * 1.0  # together, not one after another (4 x 1.0 s)


def test_in_a_batch_only_the_failed_request_carries_the_error(server):
    srv = server("--fail-instruction", "stove")
    policy = policy_for(srv.url)
    try:
        good, bad = observation(stream=0), observation(stream=1, instruction="lift the stove")
        results = policy.act_batch([good, bad])
    finally:
        policy.close()
    np.testing.assert_allclose(results[0], expected(good))
    assert isinstance(results[1], InfrastructureError)


def test_a_reply_the_client_cannot_read_or_a_request_it_cannot_make_is_the_clients_failure(server):
    srv = server()

    class Misreading(served.ServedTestPolicy):
        def decode(self, reply, observation):
            return reply["actions"]  # the wrong key: a protocol mismatch, not the model's behaviour

    class Misencoding(served.ServedTestPolicy):
        def encode(self, observation):
            return {"image": observation.agentview_image.tolist()}  # no image in this observation: a client bug

    for policy_class, message in ((Misreading, "could not read the reply .* KeyError"), (Misencoding, "encode")):
        policy = policy_class(served.ServedTestConfig(server=srv.url))
        try:
            with pytest.raises(ClientError, match=message) as raised:
                policy.act(observation())
            assert raised.value.kind == "client"
        finally:
            policy.close()


def test_a_server_killed_mid_run_stops_the_run_naming_the_url(server):
    srv = server("--die-after", "2")
    policy = policy_for(srv.url, connect_retries=2, backoff_s=0.05)
    try:
        for step in range(2):
            policy.act(observation(step))
        with pytest.raises(ServerUnavailable, match="connection refused") as caught:
            policy.act_batch([observation(2, stream=0), observation(2, stream=1)])
    finally:
        policy.close()
    assert srv.url in str(caught.value)
    assert srv.process.wait(timeout=5) != 0


def test_a_bad_url_is_one_clear_line():
    from conflictbench.core import UserError

    with pytest.raises(UserError, match="not an http:// or https:// URL: 'localhost:8000'"):
        PolicyClient("localhost:8000")


# -- what happens to an episode the infrastructure ended -------------------------------------------


def record(episode_id: str, case_id: str | None = None, error: str | None = None) -> EpisodeRecord:
    return episode_record(
        policy="served-test",
        task_id=1,
        instruction="put the bowl on the plate",
        case_id=case_id,
        family="physical" if case_id else None,
        level="L1" if case_id else None,
        episode_id=episode_id,
        error=error,
        steps=3,
        eef_pos=np.zeros((4, 3)),
        actions=np.zeros((3, 7)),
        raw_actions=np.zeros((3, 7)),
    )


def test_infrastructure_and_simulator_failures_are_left_out_policy_errors_are_not():
    infra = record("c1", "case-1", error=f"{INFRASTRUCTURE_ERROR_PREFIX}: http://x/act answered HTTP 500")
    crash = record("c2", "case-2", error=f"{SIMULATOR_ERROR_PREFIX}: the worker process died")
    wrong = record("c3", "case-3", error="policy returned a non-finite action (NaN or inf)")
    assert infra.infrastructure_failed and not infra.simulator_failed
    assert crash.infrastructure_failed and crash.simulator_failed
    assert not wrong.infrastructure_failed
    pairs, counts = pair_up([record("r"), infra, crash, wrong])
    assert [p.conflict.episode_id for p in pairs] == ["c3"]
    assert [r.episode_id for r in counts.unserved] == ["c1"] and [r.episode_id for r in counts.crashed] == ["c2"]
    assert [r.episode_id for r in counts.policy_errors] == ["c3"]


def test_an_infrastructure_failure_is_stored_for_the_record_but_played_again(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("r"))
    failed = store.write(record("c1", "case-1", error=f"{INFRASTRUCTURE_ERROR_PREFIX}: lost"))
    assert failed.parent.parent == store.replay_dir
    assert store.stored_ids() == {"r"} and store.replay_ids() == {"c1"}  # the planner replays c1
    assert {r.episode_id: r.error for r in store.records()} == {"r": None, "c1": f"{INFRASTRUCTURE_ERROR_PREFIX}: lost"}
    assert len(store) == 2

    store.write(record("c1", "case-1"))  # the replay succeeded: it replaces the failed attempt
    assert store.stored_ids() == {"r", "c1"} and store.replay_ids() == set()
    assert not failed.exists() and [r.error for r in store.records()] == [None, None]


def test_a_replay_stored_before_its_failed_attempt_was_removed_counts_once(tmp_path):
    store = EpisodeStore(tmp_path)
    failed = store.write(record("c1", "case-1", error=f"{INFRASTRUCTURE_ERROR_PREFIX}: lost"))
    saved = failed.read_bytes()
    kept = store.write(record("c1", "case-1"))
    failed.write_bytes(saved)  # as if the run had been killed between storing the replay and removing the attempt
    assert store.files() == [kept] and store.replay_ids() == set()
    assert [r.error for r in store.records()] == [None]
