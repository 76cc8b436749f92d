"""The openvla and openvla-oft policies against servers behaving as upstream's deploy.py (real FastAPI on 127.0.0.1)."""

from __future__ import annotations

import numpy as np
import pytest
from deploy_standin import start_standin
from deploy_standin_model import PROPRIO, STATS, normalized_for, prompt_of, unnormalized

from conflictbench import InfrastructureError, ServerUnavailable, UserError
from conflictbench.core import PolicyTraits
from conflictbench.hosting.openvla_family import center_crop, env_gripper, policy_image
from conflictbench.testing import camera_observation
from conflictbench_openvla.client import OftConfig, OpenVlaConfig, load

observation = camera_observation


@pytest.fixture(scope="module")
def openvla_server(tmp_path_factory):
    server, url = start_standin(tmp_path_factory.mktemp("openvla"), "openvla", "--fail-on", "failing")
    yield url
    server.stop()


@pytest.fixture(scope="module")
def oft_server(tmp_path_factory):
    server, url = start_standin(tmp_path_factory.mktemp("oft"), "oft", "--fail-on", "failing")
    yield url
    server.stop()


def openvla(url: str, **settings):
    return load("openvla", OpenVlaConfig(server=url, checkpoint="stand-in", connect_retries=0, **settings))


def oft(url: str, **settings):
    return load("openvla-oft", OftConfig(server=url, checkpoint="stand-in", connect_retries=0, **settings))


def expected_openvla(obs, key: str, crop: bool = True) -> np.ndarray:
    image = policy_image(obs.agentview_image, crop=crop)
    return env_gripper(
        unnormalized(normalized_for([image], prompt_of(obs.instruction), None)[0], STATS[key]["action"], 0)
    )


def test_openvla_sends_the_cropped_image_and_the_suites_key_and_executes_one_action(openvla_server):
    policy = openvla(openvla_server)
    try:
        for suite in ("libero_goal", "libero_10"):
            obs = observation(2, suite=suite)
            action = policy.act(obs)
            assert action.shape == (7,)
            np.testing.assert_allclose(action, expected_openvla(obs, suite), rtol=0, atol=1e-12)
        obs = observation(2, suite="libero_goal")  # the same image uncropped would have given another action
        assert not np.allclose(policy.act(obs), expected_openvla(obs, "libero_goal", crop=False))
    finally:
        policy.close()


def test_openvla_without_the_crop_sends_the_resized_image(openvla_server):
    policy = openvla(openvla_server, center_crop=False)
    try:
        obs = observation(1)
        np.testing.assert_allclose(policy.act(obs), expected_openvla(obs, "libero_goal", crop=False), atol=1e-12)
    finally:
        policy.close()


def test_the_no_noops_key_and_a_literal_key_reach_the_server(openvla_server):
    no_noops, literal = (
        openvla(openvla_server, unnorm_key="suite_no_noops"),
        openvla(openvla_server, unnorm_key="libero_10"),
    )
    try:
        obs = observation(0, suite="libero_goal")
        np.testing.assert_allclose(no_noops.act(obs), expected_openvla(obs, "libero_goal_no_noops"), atol=1e-12)
        np.testing.assert_allclose(literal.act(obs), expected_openvla(obs, "libero_10"), atol=1e-12)
    finally:
        no_noops.close()
        literal.close()


def test_a_key_the_checkpoint_lacks_fails_that_request_only_as_infrastructure(openvla_server):
    policy = openvla(openvla_server)
    try:
        results = policy.act_batch([observation(0, suite="libero_90", stream=0), observation(0, stream=1)])
        assert isinstance(results[0], InfrastructureError) and 'answered "error"' in str(results[0])
        assert isinstance(results[1], np.ndarray) and results[1].shape == (7,)
        failed = policy.act_batch([observation(0, "failing")])[0]
        assert isinstance(failed, InfrastructureError)
    finally:
        policy.close()


def test_a_gripper_of_exactly_one_half_is_sent_as_zero_as_upstreams_sign_does(openvla_server):
    policy = openvla(openvla_server)
    try:
        assert policy.act(observation(0, "open the drawer halfway"))[6] == 0.0
    finally:
        policy.close()


def test_oft_sends_uncropped_images_and_the_raw_state_and_executes_the_chunk(oft_server):
    policy = oft(oft_server)
    try:
        obs = observation(4)
        chunk = policy.act(obs)
        assert chunk.shape == (8, 7)
        images = [center_crop(policy_image(img, crop=False)) for img in (obs.agentview_image, obs.wrist_image)]
        low, high = np.asarray(PROPRIO["q01"]), np.asarray(PROPRIO["q99"])
        proprio = np.clip(2 * (obs.state - low) / (high - low + 1e-8) - 1, -1, 1)
        normalized = normalized_for(images, prompt_of(obs.instruction), proprio)
        np.testing.assert_allclose(chunk, env_gripper(unnormalized(normalized, STATS["libero_goal"]["action"], 1e-8)))
        twice = [center_crop(policy_image(img, crop=True)) for img in (obs.agentview_image, obs.wrist_image)]
        assert not np.allclose(normalized_for(twice, prompt_of(obs.instruction), proprio), normalized)
    finally:
        policy.close()


def test_oft_executes_the_last_actions_of_each_chunk_where_fewer_are_asked_as_upstreams_deque_does(oft_server):
    whole, last = oft(oft_server), oft(oft_server, chunk_length=5)
    try:
        chunk = whole.act(observation(0))
        assert np.array_equal(last.act(observation(0)), chunk[3:])  # deque(maxlen=5).extend(chunk of 8)
    finally:
        whole.close()
        last.close()


def test_a_chunk_shorter_than_asked_is_executed_whole_as_upstreams_deque_does(oft_server):
    whole, more = oft(oft_server), oft(oft_server, chunk_length=9)
    try:
        assert np.array_equal(more.act(observation(0)), whole.act(observation(0)))
    finally:
        whole.close()
        more.close()


def test_traits_follow_upstreams_evaluation(openvla_server):
    policy = openvla(openvla_server)
    try:
        traits = PolicyTraits(policy)
        assert traits.warmup_steps == 10 and traits.needs_images and traits.image_size == 256
        assert traits.max_steps == {"libero_spatial": 220, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
    finally:
        policy.close()


def test_the_server_and_its_checkpoint_name_are_the_identity(openvla_server):
    first, second = openvla(openvla_server), openvla(openvla_server)
    other = load("openvla", OpenVlaConfig(server=openvla_server, checkpoint="another", connect_retries=0))
    try:
        unreported = {"checkpoint": "stand-in", "max_batch": 1, "model_stack": "unreported"}  # deploy.py says nothing
        assert first.identity == second.identity == unreported
        assert other.identity != first.identity
    finally:
        for policy in (first, second, other):
            policy.close()


def test_a_server_that_dies_stops_the_run_with_its_address(tmp_path):
    server, url = start_standin(tmp_path, "openvla", "--die-on", "die now")
    policy = openvla(url)
    try:
        with pytest.raises(ServerUnavailable, match="cannot be reached") as failure:
            policy.act(observation(0, "die now"))
        assert url in str(failure.value)
    finally:
        policy.close()
        server.stop()


@pytest.mark.parametrize(
    "name, settings, message",
    [
        ("openvla", {"server": "", "checkpoint": ""}, "needs model.checkpoint=DIR .* or model.server=http://HOST:PORT"),
        ("openvla", {"server": "", "checkpoint": "{tmp}"}, "is not an OpenVLA checkpoint .config.json"),
        ("openvla", {"server": "", "checkpoint": "{tmp}/none"}, "no checkpoint folder at"),
        ("openvla-oft", {"server": "", "checkpoint": "{tmp}"}, "served by OFT's own vla-scripts/deploy.py"),
        ("openvla", {"checkpoint": ""}, "also needs model.checkpoint=NAME"),
        ("openvla", {"server": "ftp://h:1"}, "not an http:// or https:// URL"),
        ("openvla-oft", {"chunk_length": 0}, "model.chunk_length must be >= 1"),
        ("openvla", {"server": "http://127.0.0.1:9"}, "cannot be reached"),
    ],
)
def test_user_mistakes_are_one_line_errors(tmp_path, name, settings, message):
    config = {"openvla": OpenVlaConfig, "openvla-oft": OftConfig}[name]
    settings = {key: value.format(tmp=tmp_path) if isinstance(value, str) else value for key, value in settings.items()}
    values = {"server": "http://127.0.0.1:9", "checkpoint": "x", "connect_retries": 0, **settings}
    with pytest.raises((UserError, ServerUnavailable), match=message):
        load(name, config(**values))
