"""The univla policy against a server speaking our UniVLA protocol (real FastAPI on 127.0.0.1, numpy stand-in)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from univla_standin import start_standin
from univla_standin_model import STATISTICS, chunk_for, latent_tokens, prompt_of

from conflictbench import InfrastructureError, UserError, sampling_seed
from conflictbench.core import PolicyTraits
from conflictbench.hosting.openvla_family import env_gripper, policy_image, unnormalize
from conflictbench.testing import camera_observation
from conflictbench_univla.client import UnivlaConfig, load
from conflictbench_univla.processing import TemporalEnsemble, history_text


@pytest.fixture(scope="module")
def standin(tmp_path_factory):
    server, url = start_standin(tmp_path_factory.mktemp("univla"), "--fail-on", "failing")
    yield url
    server.stop()


def univla(url: str, **settings):
    return load("univla", UnivlaConfig(server=url, checkpoint="stand-in", connect_retries=0, **settings))


def upstream_loop(observations) -> list[np.ndarray]:
    """UniVLA's evaluation loop restated for one episode: the history of the last query, the window, the key."""
    history, ensemble, actions = "", TemporalEnsemble(12), []
    for obs in observations:
        prompt, seed = prompt_of(obs.instruction, history), sampling_seed(obs) % 2**63
        image = policy_image(obs.agentview_image, crop=True)
        history = history_text(latent_tokens(prompt, seed))
        normalized = ensemble.add(chunk_for(image, prompt, seed))
        actions.append(env_gripper(unnormalize(normalized, STATISTICS[obs.suite])))
    return actions


def episode(stream: int = 0, steps: int = 4, text: str = "put the bowl on the plate", suite: str = "libero_goal"):
    return [camera_observation(step, text, stream=stream, suite=suite) for step in range(steps)]


def test_each_step_carries_the_last_querys_tokens_and_executes_the_ensembled_action(standin):
    policy = univla(standin)
    try:
        observations = episode()
        served = [policy.act(obs) for obs in observations]
        expected = upstream_loop(observations)
        for got, want in zip(served, expected, strict=True):
            assert got.shape == (7,)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        no_history = upstream_loop(observations[1:2])[0]  # the second step as if it had no history: another action
        assert not np.allclose(served[1], no_history)
    finally:
        policy.close()


def test_streams_keep_their_own_history_and_window(standin):
    policy = univla(standin)
    try:
        first, second = episode(0, 3, "open the drawer"), episode(1, 3, "close it", suite="libero_10")
        interleaved = [policy.act_batch([a, b]) for a, b in zip(first, second, strict=True)]
        for step, (a, b) in enumerate(interleaved):
            np.testing.assert_allclose(a, upstream_loop(first)[step], atol=1e-12)
            np.testing.assert_allclose(b, upstream_loop(second)[step], atol=1e-12)
    finally:
        policy.close()


def test_a_new_episode_on_a_stream_starts_without_history_or_window(standin):
    policy = univla(standin)
    try:
        for obs in episode(steps=3):
            policy.act(obs)
        fresh = policy.act(camera_observation(0, "put the bowl on the plate"))
        np.testing.assert_allclose(fresh, upstream_loop(episode(steps=1))[0], atol=1e-12)
    finally:
        policy.close()


def test_fewer_latent_tokens_make_a_shorter_history_as_upstreams(standin):
    policy = univla(standin)
    try:
        first, second = episode(steps=2, text="wave briefly")
        policy.act(first)
        assert policy.encode(second)["history"].count("<ACT_") == 3
    finally:
        policy.close()


def test_a_checkpoint_with_only_no_noops_statistics_is_unnormalized_with_those(tmp_path):
    server, url = start_standin(tmp_path, "--no-noops")
    policy = univla(url)
    try:
        obs = camera_observation(0, suite="libero_10")
        assert policy.encode(obs)["unnorm_key"] == "libero_10_no_noops"
        np.testing.assert_allclose(policy.act(obs), upstream_loop([obs])[0], atol=1e-12)
    finally:
        policy.close()
        server.stop()


def test_a_server_error_or_a_missing_key_fails_that_request_only(standin):
    policy = univla(standin)
    try:
        failing, unknown = camera_observation(0, "failing"), camera_observation(0, stream=1, suite="libero_90")
        results = policy.act_batch([failing, unknown, camera_observation(0, stream=2)])
        assert isinstance(results[0], InfrastructureError) and "the model failed on purpose" in str(results[0])
        assert isinstance(results[1], InfrastructureError) and "no statistics 'libero_90'" in str(results[1])
        assert isinstance(results[2], np.ndarray)
    finally:
        policy.close()


def test_traits_follow_univlas_evaluation(standin):
    policy = univla(standin)
    try:
        traits = PolicyTraits(policy)
        assert traits.warmup_steps == 10 and traits.needs_images
        assert traits.max_steps == {"libero_spatial": 240, "libero_object": 300, "libero_goal": 320, "libero_10": 550}
        assert policy.identity == {"checkpoint": "sha256:standin", "max_batch": 1, "model_stack": "unreported"}
    finally:
        policy.close()


def test_a_server_that_does_not_say_its_window_and_statistics_is_refused(tmp_path):
    server, url = start_standin(tmp_path, "--no-metadata")
    try:
        with pytest.raises(UserError, match="does not say its ensembling window and action statistics"):
            univla(url)
    finally:
        server.stop()


def test_a_checkpoint_folder_needs_univlas_code_and_the_decoder(tmp_path, monkeypatch):
    monkeypatch.delenv("UNIVLA_CODE", raising=False)
    with pytest.raises(UserError, match="UniVLA's model code is in no package: set UNIVLA_CODE"):
        load("univla", UnivlaConfig(checkpoint=str(tmp_path)))
    monkeypatch.setenv("UNIVLA_CODE", str(Path(__file__).parent / "standin_univla_code"))
    (tmp_path / "config.json").write_text('{"model_type": "openvla"}')
    (tmp_path / "model.safetensors").write_bytes(b"")
    with pytest.raises(UserError, match="lacks action_decoder.pt"):
        load("univla", UnivlaConfig(checkpoint=str(tmp_path)))
