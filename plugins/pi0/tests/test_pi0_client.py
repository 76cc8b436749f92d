"""The client against openpi's own server (openpi-server from PyPI, a real process on 127.0.0.1)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from conflictbench.core import InfrastructureError, Observation, ServerProcess, ServerUnavailable, UserError, free_port
from conflictbench.core.sampling import sampling_seed
from conflictbench_pi0.client import PiConfig, load
from conflictbench_pi0.processing import camera_image

sys.path.insert(0, str(Path(__file__).parent))
from numpy_openpi_server import CHUNK, FAIL_PROMPT, actions_for  # noqa: E402

SERVER_SCRIPT = Path(__file__).with_name("numpy_openpi_server.py")


def start_openpi_server(tmp_path: Path, *args: str) -> tuple[ServerProcess, str]:
    port = free_port()
    server = ServerProcess(
        [sys.executable, str(SERVER_SCRIPT), str(port), *args],
        name="openpi-test",
        health_url=f"http://127.0.0.1:{port}/healthz",
        startup_timeout_s=60,
        log_dir=tmp_path,
    )
    return server.start(), f"ws://127.0.0.1:{port}"


@pytest.fixture(scope="module")
def openpi_server(tmp_path_factory):
    server, url = start_openpi_server(tmp_path_factory.mktemp("openpi"))
    yield url
    server.stop()


def observation(step: int = 0, prompt: str = "put the bowl on the plate", episode: str = "e1", stream: int = 0):
    rng = np.random.default_rng(step)
    agentview = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)
    agentview[:128] //= 4  # LIBERO's top rows are the bottom of the upright view: dark, after turning
    wrist = rng.integers(0, 256, (256, 256, 3), dtype=np.uint8)
    wrist[:, :128] //= 4
    state = rng.normal(size=8)
    return Observation(
        step=step,
        instruction=prompt,
        eef_pos=state[:3],
        eef_quat=np.array([0.0, 0.0, 0.0, 1.0]),
        gripper_qpos=state[6:],
        state=state,
        agentview_image=agentview,
        wrist_image=wrist,
        stream=stream,
        episode_id=episode,
    )


def policy(url: str, name: str = "pi05", **settings):
    return load(name, PiConfig(server=url, checkpoint="stand-in", connect_retries=0, **settings))


def expected_request(obs: Observation) -> dict:
    return {
        "observation/image": camera_image(obs.agentview_image),
        "observation/wrist_image": camera_image(obs.wrist_image),
        "observation/state": obs.state,
        "prompt": obs.instruction,
        "conflictbench/noise_seed": sampling_seed(obs) % 2**63,
    }


def test_the_request_holds_openpis_keys_with_its_types_and_the_first_five_actions_are_executed(openpi_server):
    pi = policy(openpi_server)
    try:
        obs = observation(step=3)
        reply = pi.client.request(pi.encode(obs))
        assert reply["received"] == {
            "observation/image": ["uint8", [224, 224, 3]],
            "observation/wrist_image": ["uint8", [224, 224, 3]],
            "observation/state": ["float64", [8]],
            "prompt": "str",
            "conflictbench/noise_seed": "int",
        }
        assert reply["actions"].shape == (CHUNK, 7)
        chunk = pi.act(obs)
        np.testing.assert_allclose(chunk, actions_for(expected_request(obs))[:5])
        assert chunk[0, 0] > 0  # the server saw the images upright (the dark half on top in LIBERO's render)
    finally:
        pi.close()


def test_replan_steps_sets_how_much_of_each_chunk_is_executed(openpi_server):
    pi = policy(openpi_server, replan_steps=8)
    try:
        assert pi.act(observation()).shape == (8, 7)
    finally:
        pi.close()


def test_the_noise_seed_comes_from_the_episode_and_step_never_the_call_order(openpi_server):
    pi = policy(openpi_server)
    try:
        first = pi.act(observation(step=2, episode="a"))
        pi.act(observation(step=5, episode="b", stream=1))
        again = pi.act(observation(step=2, episode="a", stream=1))
        np.testing.assert_array_equal(first, again)
        seeds = [pi.encode(observation(step=step, episode="a"))["conflictbench/noise_seed"] for step in range(40)]
        assert len(set(seeds)) == 40 and all(0 <= seed < 2**63 for seed in seeds)  # a signed 64-bit int
        assert any(sampling_seed(observation(step=step, episode="a")) >= 2**63 for step in range(40))
    finally:
        pi.close()


def test_an_error_frame_is_an_infrastructure_failure_and_the_next_request_reconnects(openpi_server):
    pi = policy(openpi_server, resends=0)  # reconnecting after the error costs no resend
    try:
        with pytest.raises(InfrastructureError, match="answered an error: RuntimeError: the model failed on purpose"):
            pi.act(observation(prompt=FAIL_PROMPT))
        assert pi.act(observation()).shape == (5, 7)  # openpi closed that connection; the client opened another
    finally:
        pi.close()


def test_a_reply_of_another_shape_is_an_infrastructure_failure(openpi_server):
    pi = policy(openpi_server)
    try:
        with pytest.raises(InfrastructureError, match=r"could not read the reply.*expected \(horizon, 7\)"):
            pi._decode({"actions": np.zeros((10, 8))}, observation())
        with pytest.raises(InfrastructureError, match="could not read the reply"):
            pi._decode({"no actions": 1}, observation())
    finally:
        pi.close()


def test_a_server_hosting_another_pi_policy_is_refused(tmp_path):
    server, url = start_openpi_server(tmp_path, "--policy-type", "pi0")
    try:
        with pytest.raises(UserError, match="hosts a pi0 policy, not pi05"):
            policy(url, "pi05")
        pi = policy(url, "pi0")
        pi.close()
    finally:
        server.stop()


def test_a_server_that_went_away_stops_the_run_naming_its_url(tmp_path):
    server, url = start_openpi_server(tmp_path)
    pi = policy(url)
    try:
        assert pi.act(observation()).shape == (5, 7)
        server.stop()
        with pytest.raises(ServerUnavailable, match=url):
            pi.act(observation(step=1))
    finally:
        pi.close()
