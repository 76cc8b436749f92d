"""The gr00t policy against a server that behaves as NVIDIA's (real ZeroMQ on 127.0.0.1, numpy stand-in model)."""

from __future__ import annotations

import re
import time

import numpy as np
import pytest
from gr00t_standin import start_standin
from nvidia_standin_server import actions_for

from conflictbench import InfrastructureError, Observation, ServerUnavailable, UserError, sampling_seed
from conflictbench.core import LIBERO_SUITES, PolicyTraits
from conflictbench.hosting.zeromq import ZmqTransport
from conflictbench.testing import camera_observation
from conflictbench_gr00t.client import Gr00tConfig, load
from conflictbench_gr00t.processing import env_actions, gr00t_observation
from conflictbench_gr00t.protocol import get_action_request

observation = camera_observation
#: One row as GR00T's client sends it: two 256-px images, the 8-D state, the task.
ROW = (np.zeros((256, 256, 3), np.uint8), np.zeros((256, 256, 3), np.uint8), np.zeros(8), "put the bowl on the plate")


def config(url: str, **settings) -> Gr00tConfig:
    return Gr00tConfig(server=url, checkpoint="stand-in", connect_retries=0, **settings)


@pytest.fixture
def standin(tmp_path):
    server, url = start_standin(tmp_path, "--fail-on", "malformed", "--die-on", "die now")
    yield url
    server.stop()


def expected_chunk(obs: Observation) -> np.ndarray:
    """What the stand-in answers for ``obs`` as GR00T's client sends it, mapped as GR00T's client maps it."""
    sent = gr00t_observation(obs.agentview_image, obs.wrist_image, obs.state, obs.instruction)
    options = {"conflictbench/noise_seed": sampling_seed(obs) % 2**63}
    return env_actions(actions_for(sent, options, horizon=16))


def test_a_query_executes_the_first_eight_actions_of_the_servers_chunk(standin):
    policy = load("gr00t", config(standin))
    try:
        obs = observation(3)
        actions = policy.act(obs)
        assert actions.shape == (8, 7)
        np.testing.assert_allclose(actions, expected_chunk(obs)[:8], rtol=1e-6)
        assert actions[:, 6].tolist() == [1.0, -1.0, 0.0] * 2 + [1.0, -1.0]  # the stand-in's gripper 0, 1, 0.5
    finally:
        policy.close()


def test_the_episode_and_step_reach_the_server_as_the_seed_and_the_text_as_it_is(standin):
    policy = load("gr00t", config(standin))
    try:
        first, later = policy.act(observation(0)), policy.act(observation(8))
        assert first[0, 5] != later[0, 5]  # the seed (episode, step) differs
        short = policy.act(observation(0, instruction="open it"))
        assert short[0, 4] != first[0, 4]  # the text's length arrived
    finally:
        policy.close()


def test_traits_follow_gr00ts_evaluation_and_a_shorter_budget_counts_for_every_suite(standin):
    policy = load("gr00t", config(standin))
    shorter = load("gr00t", config(standin, max_steps=16))
    try:
        traits = PolicyTraits(policy)
        assert traits.warmup_steps == 0 and traits.max_steps == {suite: 720 for suite in LIBERO_SUITES}
        assert PolicyTraits(shorter).max_steps == {suite: 16 for suite in LIBERO_SUITES}
    finally:
        policy.close()
        shorter.close()


def test_nvidias_server_says_nothing_about_its_model_so_the_given_name_is_the_identity(standin):
    named = [load("gr00t", Gr00tConfig(server=standin, checkpoint=name)) for name in ("a", "b")]
    try:
        assert [p.identity for p in named] == [
            {"checkpoint": name, "max_batch": 1, "model_stack": "unreported"} for name in ("a", "b")
        ]  # NVIDIA's server says nothing of its stack either
    finally:
        for policy in named:
            policy.close()


def test_a_malformed_reply_fails_that_request_only(standin):
    policy = load("gr00t", config(standin))
    try:
        results = policy.act_batch([observation(0, "a malformed one", stream=0), observation(0, "fine", stream=1)])
        assert isinstance(results[0], InfrastructureError) and "action.gripper" in str(results[0])
        assert isinstance(results[1], np.ndarray) and results[1].shape == (8, 7)
        assert policy.act(observation(1)).shape == (8, 7)  # the connection still works
    finally:
        policy.close()


def test_a_server_that_dies_stops_the_run_with_its_address(standin):
    policy = load("gr00t", config(standin, request_timeout_s=3.0, connect_timeout_s=1.0))
    try:
        # the request in flight is lost with the connection (not a slow model): reconnecting finds no server
        started = time.monotonic()
        with pytest.raises(ServerUnavailable, match="cannot be reached") as failure:
            policy.act(observation(0, "die now"))
        assert standin in str(failure.value) and time.monotonic() - started < 3.0  # not the 3 s reply limit
        with pytest.raises(ServerUnavailable, match="cannot be reached"):
            policy.act(observation(1))
    finally:
        policy.close()


def test_an_api_token_is_sent_and_a_wrong_one_is_refused(tmp_path):
    server, url = start_standin(tmp_path, api_token="secret")
    try:
        good = load("gr00t", config(url, api_token="secret"))
        try:
            assert good.act(observation(0)).shape == (8, 7)
        finally:
            good.close()
        with pytest.raises(ServerUnavailable, match="Unauthorized"):
            load("gr00t", config(url, api_token="wrong", connect_timeout_s=1.0))
    finally:
        server.stop()


def test_a_server_of_nvidias_main_branch_is_named_before_any_episode(tmp_path):
    """Isaac-GR00T's main since 3df8b38 decodes arrays with msgpack_numpy only: our np.save maps reach its policy
    as maps, and every get_action fails. The run must say so in one line when it connects, not play episodes."""
    server, url = start_standin(tmp_path, "--revision", "main")
    try:
        transport = ZmqTransport(url)  # what such a server does with our request: the stand-in is main's
        transport.connect(timeout=5.0)
        try:
            request = get_action_request(gr00t_observation(*ROW))
            with pytest.raises(InfrastructureError, match=re.escape("must be a numpy array. Got <class 'dict'>")):
                transport.exchange(request, timeout=5.0)
        finally:
            transport.close()
        with pytest.raises(UserError) as failure:
            load("gr00t", config(url))
        message = str(failure.value)
        assert "\n" not in message and url in message
        assert all(name in message for name in ("3df8b38", "n1.7-release", "23ace64f17aa5015259b8609d371eb61a357c776"))
    finally:
        server.stop()


def test_a_server_of_the_release_speaks_our_wire_and_answers_its_modality_config(standin):
    transport = ZmqTransport(standin)
    transport.connect(timeout=5.0)
    try:
        reply = transport.exchange({"endpoint": "get_modality_config"}, timeout=5.0)
    finally:
        transport.close()
    assert reply["action"]["__ModalityConfig_class__"] is True
    assert reply["action"]["as_json"]["delta_indices"] == list(range(16))
    policy = load("gr00t", config(standin))
    try:
        assert policy.act(observation(0)).shape == (8, 7)
    finally:
        policy.close()


@pytest.mark.parametrize(
    "settings, message",
    [
        ({}, "no checkpoint folder at x"),
        ({"checkpoint": ""}, "model=gr00t needs model.checkpoint=DIR (a local checkpoint folder) or model.server="),
        ({"server": "ws://127.0.0.1:5555"}, "not a tcp://HOST:PORT URL"),
        ({"server": "tcp://127.0.0.1:5555", "checkpoint": ""}, "also needs model.checkpoint=NAME"),
        ({"server": "tcp://127.0.0.1:5555", "action_steps": 0}, "model.action_steps must be >= 1"),
    ],
)
def test_user_mistakes_are_user_errors(settings, message):
    cfg = {"checkpoint": "x", **settings}
    with pytest.raises(UserError, match=re.escape(message)):
        load("gr00t", Gr00tConfig(**cfg))
