"""Our GR00T server's protocol with a numpy stand-in backend (real ZeroMQ on 127.0.0.1): NVIDIA's REQ clients
unchanged, its error answers, batching across clients, and our client reading what is hosted."""

from __future__ import annotations

import asyncio
import threading
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import zmq
from nvidia_standin_server import from_bytes, to_bytes

from conflictbench.testing import camera_observation
from conflictbench.testing.plugin_tests import check_serve_refuses, lerobot_checkpoint_errors, server_in_thread
from conflictbench_gr00t.client import Gr00tConfig, load
from conflictbench_gr00t.processing import env_actions, gr00t_observation
from conflictbench_gr00t.protocol import ACTION_KEYS, LANGUAGE_KEY
from conflictbench_gr00t.server import Gr00tPolicyServer, Row

PLUGIN_ROOT = Path(__file__).resolve().parents[1]

HORIZON = 16


class StandInBackend:
    """Chunks that follow each row's image, state, text and seed; records each call's rows; can be held."""

    def __init__(self):
        self.calls: list[list[Row]] = []
        self.hold, self.entered = threading.Event(), threading.Event()
        self.hold.set()
        self.metadata = {"policy_type": "groot", "checkpoint_fingerprint": "sha256:standin", "action_horizon": HORIZON}

    def infer_batch(self, rows: list[Row]) -> list[dict[str, np.ndarray]]:
        self.entered.set()
        self.hold.wait(10)
        self.calls.append(rows)
        if any("fail" in row.instruction for row in rows):
            raise RuntimeError("the model failed on purpose")
        return [chunk_for(row) for row in rows]


def chunk_for(row: Row) -> dict[str, np.ndarray]:
    obs = row.observation
    values = [obs["video.image"][0, 0, :128].mean() / 255, obs["video.wrist_image"][0, 0, :, :128].mean() / 255,
              obs["state.x"][0, 0, 0], obs["state.gripper"][0, 0, 1], len(row.instruction) / 99,
              (row.seed or 0) % 1000 / 1000]  # fmt: skip
    steps = np.arange(1, HORIZON + 1, dtype=np.float32)[:, None]
    chunk = {key: (values[i] * steps).astype(np.float32) for i, key in enumerate(ACTION_KEYS[:-1])}
    chunk["action.gripper"] = np.tile(np.array([[0.0], [1.0]], np.float32), (HORIZON // 2, 1))
    return chunk


@contextmanager
def serving(backend, max_batch: int = 2, api_token: str | None = None):
    try:
        with server_in_thread(lambda: Gr00tPolicyServer(backend, max_batch, api_token)) as (server, port):
            backend.server = server  # for tests that watch its queue
            yield f"tcp://127.0.0.1:{port}"
    finally:
        backend.hold.set()


@contextmanager
def nvidia_client(url: str):
    """A REQ socket as NVIDIA's ``PolicyClient`` uses it, with the stand-in's independent codec."""
    context = zmq.Context()
    socket = context.socket(zmq.REQ)
    socket.setsockopt(zmq.RCVTIMEO, 10_000)
    socket.connect(url)

    def call(request: dict):
        socket.send(to_bytes(request))
        return from_bytes(socket.recv())

    try:
        yield call
    finally:
        socket.close(linger=0)
        context.term()


def observation_request(step: int = 0, text: str = "put the bowl on the plate", seed: int | None = 3) -> dict:
    obs = camera_observation(step, text)
    sent = gr00t_observation(obs.agentview_image, obs.wrist_image, obs.state, obs.instruction)
    options = None if seed is None else {"conflictbench/noise_seed": seed}
    return {"endpoint": "get_action", "data": {"observation": sent, "options": options}}


def test_nvidias_client_gets_actions_errors_as_answers_and_the_server_goes_on():
    backend = StandInBackend()
    with serving(backend) as url, nvidia_client(url) as call:
        assert call({"endpoint": "ping"}) == {"status": "ok", "message": "Server is running"}
        action, info = call(observation_request(2))
        row = backend.calls[-1][0]
        assert row.seed == 3 and row.instruction == "put the bowl on the plate" and len(backend.calls[-1]) == 2
        for key in ACTION_KEYS:
            assert action[key].dtype == np.float32 and action[key].shape == (1, HORIZON, 1)
            np.testing.assert_array_equal(action[key][0], chunk_for(row)[key])
        assert info == {"batch_size": 1}
        broken = observation_request(1)
        broken["data"]["observation"]["state.x"] = np.zeros((1, 1, 2), np.float32)
        assert call({"endpoint": "kill"}) == {"error": "Unknown endpoint: kill"}
        assert "'state.x' must be float32 (B, 1, 1)" in call(broken)["error"]
        assert call(observation_request(4, "fail here")) == {"error": "RuntimeError: the model failed on purpose"}
        assert isinstance(call(observation_request(5))[0], dict)  # still serving
        assert call({"endpoint": "conflictbench_metadata"})["max_batch"] == 2


def test_requests_waiting_from_several_clients_share_one_call_of_the_fixed_shape():
    backend = StandInBackend()
    with (
        serving(backend, max_batch=4) as url,
        nvidia_client(url) as a,
        nvidia_client(url) as b,
        nvidia_client(url) as c,
    ):
        backend.hold.clear()  # the first request's call is held, so the next two wait for one call together
        replies: dict[str, dict] = {}

        def ask(call, text: str) -> None:
            replies[text] = call(observation_request(0, text))[0]

        first = threading.Thread(target=ask, args=(a, "task one"))
        first.start()
        assert backend.entered.wait(10)  # the first call is in the model, held
        rest = [threading.Thread(target=ask, args=(call, text)) for call, text in ((b, "task two"), (c, "task six"))]
        for thread in rest:
            thread.start()
        for _ in range(200):
            if backend.server.batcher.queued == 2:
                break
            threading.Event().wait(0.05)
        backend.hold.set()
        for thread in (first, *rest):
            thread.join(10)
    assert [len(call) for call in backend.calls] == [4, 4]  # every call padded to max_batch rows
    assert [row.instruction for row in backend.calls[0]] == ["task one"] * 4
    assert sorted(row.instruction for row in backend.calls[1][:2]) == ["task six", "task two"]
    for text, action in replies.items():
        row = next(row for call in backend.calls for row in call if row.instruction == text)
        np.testing.assert_array_equal(action["action.x"][0], chunk_for(row)["action.x"])


def test_the_api_token_is_required_when_set():
    with serving(StandInBackend(), api_token="s3cret") as url, nvidia_client(url) as call:
        assert call({"endpoint": "ping"}) == {"error": "Unauthorized: Invalid API token"}
        assert call({"endpoint": "ping", "api_token": "s3cret"})["status"] == "ok"


def test_our_client_reads_what_is_hosted_and_executes_eight_actions():
    backend = StandInBackend()
    with serving(backend, max_batch=1) as url:
        policy = load("gr00t", Gr00tConfig(server=url, checkpoint="ignored", connect_retries=0))
        try:
            obs = camera_observation(6)
            actions = policy.act(obs)
            expected = env_actions({key: value[None] for key, value in chunk_for(backend.calls[-1][0]).items()})
            np.testing.assert_allclose(actions, expected[:8], rtol=1e-6)
            assert policy.identity == {"checkpoint": "sha256:standin", "max_batch": 1, "model_stack": "unreported"}
        finally:
            policy.close()


@pytest.mark.parametrize("language", [["a", "b"], "text"])
def test_a_text_list_that_does_not_match_the_rows_is_refused(language):
    request = observation_request(0)
    request["data"]["observation"][LANGUAGE_KEY] = language
    with serving(StandInBackend()) as url, nvidia_client(url) as call:
        assert "must be a list of 1 strings" in call(request)["error"]


@pytest.mark.parametrize(
    "make, fragment",
    lerobot_checkpoint_errors("groot", "vla_jepa", "not a LeRobot checkpoint (no config.json) (an Isaac-GR00T"),
)
def test_serve_command_user_errors_are_one_line_and_exit_2(tmp_path, make, fragment):
    check_serve_refuses(PLUGIN_ROOT, tmp_path, "gr00t", make(tmp_path), fragment)


def test_a_reply_that_cannot_be_built_is_still_answered_as_an_error():
    backend = StandInBackend()
    # The first row's chunk has a key the second's lacks: the two cannot be stacked into one reply.
    chunk = {"action.x": np.zeros((HORIZON, 1), np.float32)}
    backend.infer_batch = lambda rows: [chunk if row.instruction == "first" else {} for row in rows]
    with serving(backend, max_batch=1) as url, nvidia_client(url) as call:
        request = observation_request(0)
        observation = request["data"]["observation"]
        for key, value in list(observation.items()):  # the same row twice, with two texts
            observation[key] = ["first", "second"] if isinstance(value, list) else np.concatenate([value] * 2)
        assert call(request) == {"error": "KeyError: 'action.x'"}
        assert call({"endpoint": "ping"})["status"] == "ok"


def test_a_port_in_use_is_an_os_error_the_serve_command_reports_in_one_line():
    with serving(StandInBackend()) as url:
        port = int(url.rsplit(":", 1)[1])
        server = Gr00tPolicyServer(StandInBackend(), 1)
        with pytest.raises(OSError, match="Address already in use"):
            asyncio.run(server.run("127.0.0.1", port, asyncio.Event()))
