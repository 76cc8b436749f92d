"""The vla-jepa policy against a server behaving as upstream's (real websocket on 127.0.0.1, numpy stand-in model)."""

from __future__ import annotations

import numpy as np
import pytest
from jepa_standin import ACTION_STATS, start_standin, write_run
from starvla_standin_server import normalized_for

from conflictbench import InfrastructureError, Observation, ServerUnavailable, UserError, sampling_seed
from conflictbench.core import PolicyTraits
from conflictbench.testing import camera_observation
from conflictbench_vla_jepa.client import VlaJepaConfig, load
from conflictbench_vla_jepa.processing import ActionStatistics, camera_image, env_actions
from conflictbench_vla_jepa.protocol import infer_request

observation = camera_observation


@pytest.fixture
def standin(tmp_path):
    server, url = start_standin(tmp_path, "--fail-on", "failing", "--crash-on", "crashing", "--die-on", "die now")
    yield url
    server.stop()


def config(tmp_path, url: str, **settings) -> VlaJepaConfig:
    stats = settings.pop("stats", None) or str(write_run(tmp_path / "run", window=7))
    return VlaJepaConfig(server=url, checkpoint="stand-in", stats=stats, connect_retries=0, **settings)


def expected(obs: Observation, chunk_length: int = 8) -> np.ndarray:
    images = [camera_image(obs.agentview_image), camera_image(obs.wrist_image)]
    request = infer_request(images, obs.instruction, obs.state, "x", None, sampling_seed(obs) % 2**63)
    normalized = normalized_for(request["payload"], chunk=8)[0]  # float32, as the server sends it
    return env_actions(normalized, ActionStatistics.from_mapping(ACTION_STATS), chunk_length)


def test_a_query_executes_the_whole_chunk_un_normalized_with_the_runs_statistics(tmp_path, standin):
    policy = load("vla-jepa", config(tmp_path, standin))
    try:
        obs = observation(3)
        actions = policy.act(obs)
        assert actions.shape == (8, 7)  # future_action_window_size 7 + 1
        np.testing.assert_array_equal(actions, expected(obs))
        assert actions[:, 6].tolist() == [1.0, -1.0] * 4  # stand-in gripper 0.2 (closed), 0.9 (open)
        low, high = np.array(ACTION_STATS["min"][:6]), np.array(ACTION_STATS["max"][:6])
        assert np.all(actions[:, :6] >= low) and np.all(actions[:, :6] <= high)  # in the dataset's units
    finally:
        policy.close()


def test_a_given_chunk_length_overrides_the_config_and_counts_in_the_identity(tmp_path, standin):
    seven = load("vla-jepa", config(tmp_path, standin, chunk_length=7))
    eight = load("vla-jepa", config(tmp_path, standin))
    try:
        assert seven.act(observation(0)).shape == (7, 7)
        assert seven.identity != eight.identity
        assert seven.identity["checkpoint"] == "stand-in" and seven.identity["max_batch"] == 1
    finally:
        seven.close()
        eight.close()


def test_the_statistics_count_by_content_not_by_path(tmp_path, standin):
    first = load("vla-jepa", config(tmp_path, standin, stats=str(write_run(tmp_path / "a"))))
    moved = load("vla-jepa", config(tmp_path, standin, stats=str(write_run(tmp_path / "b"))))
    other = dict(ACTION_STATS, max=[1.0] * 7)
    changed_stats = write_run(tmp_path / "c", datasets={"k": {"action": other}})
    changed = load("vla-jepa", config(tmp_path, standin, stats=str(changed_stats)))
    try:
        assert first.identity == moved.identity != changed.identity
    finally:
        for policy in (first, moved, changed):
            policy.close()


def test_traits_follow_vla_jepas_evaluation(tmp_path, standin):
    policy = load("vla-jepa", config(tmp_path, standin))
    try:
        traits = PolicyTraits(policy)
        assert traits.warmup_steps == 10
        assert traits.max_steps == {"libero_spatial": 250, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
    finally:
        policy.close()


def test_server_errors_fail_that_request_only_whether_in_frame_or_as_a_text_frame(tmp_path, standin):
    policy = load("vla-jepa", config(tmp_path, standin))
    try:
        texts = ("failing", "crashing", "fine")
        results = policy.act_batch([observation(0, text, stream=i) for i, text in enumerate(texts)])
        assert isinstance(results[0], InfrastructureError) and "the model failed on purpose" in str(results[0])
        assert isinstance(results[1], InfrastructureError) and "Internal server error" in str(results[1])
        assert isinstance(results[2], np.ndarray) and results[2].shape == (8, 7)
        assert policy.act(observation(1, stream=1)).shape == (8, 7)  # the closed connection is opened again
    finally:
        policy.close()


def test_a_server_that_dies_stops_the_run_with_its_address(tmp_path, standin):
    policy = load("vla-jepa", config(tmp_path, standin))
    try:
        with pytest.raises(ServerUnavailable, match="cannot be reached") as failure:
            policy.act(observation(0, "die now"))
        assert standin in str(failure.value)
    finally:
        policy.close()


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"server": ""}, "no checkpoint folder at x"),
        (
            {"server": "", "checkpoint": "{run}"},
            "is not a LeRobot checkpoint .no config.json.*upstream's server_policy",
        ),
        ({"stats": "{missing}"}, "cannot read the statistics file"),
        ({"stats": "{nocfg}"}, "no config.yaml beside"),
        ({"stats": "{two}"}, "choose one with model.unnorm_key"),
        ({"chunk_length": -1}, "model.chunk_length must be >= 0"),
    ],
)
def test_user_mistakes_are_user_errors(tmp_path, settings, message):
    two = write_run(tmp_path / "two", datasets={"a": {"action": ACTION_STATS}, "b": {"action": ACTION_STATS}})
    nocfg = write_run(tmp_path / "nocfg")
    (nocfg.parent / "config.yaml").unlink()
    values = {"missing": tmp_path / "none.json", "two": two, "nocfg": nocfg, "run": tmp_path / "two"}
    cfg = {"server": "ws://127.0.0.1:9", "checkpoint": "x", "stats": str(write_run(tmp_path / "run"))}
    cfg.update({k: v.format(**values) if isinstance(v, str) else v for k, v in settings.items()})
    with pytest.raises(UserError, match=message):
        load("vla-jepa", VlaJepaConfig(**cfg))


def test_against_upstreams_server_the_statistics_must_be_given(tmp_path, standin):
    """Upstream's server sends no statistics: without model.stats the client cannot un-normalize."""
    with pytest.raises(UserError, match="does not send its action statistics.*give model.stats=FILE"):
        load("vla-jepa", VlaJepaConfig(server=standin, checkpoint="stand-in", connect_retries=0))
