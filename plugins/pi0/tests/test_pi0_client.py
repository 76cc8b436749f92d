"""The client against openpi's own server (openpi-server from PyPI, a real process on 127.0.0.1)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from conflictbench.core import InfrastructureError, Observation, ServerUnavailable, UserError
from conflictbench.core.sampling import sampling_seed
from conflictbench.hosting import ServerProcess, free_port
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


def fake_checkpoint(folder: Path, kind: str = "pi05", weights: bytes = b"weights") -> Path:
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(f'{{"type": "{kind}"}}')
    (folder / "model.safetensors").write_bytes(weights)
    (folder / "policy_preprocessor.json").write_text("{}")
    return folder


def identity_hash(cfg: PiConfig, checkpoint: Path) -> str:
    from conflictbench.core import PolicyTraits
    from conflictbench.sim.plan import config_hash
    from conflictbench_pi0.client import PiPolicy

    policy = PiPolicy("pi05", cfg, checkpoint)  # nothing starts before start()
    assert policy.server is None and policy.client is None
    return config_hash("pi05", cfg, PolicyTraits(policy))


def test_a_checkpoint_counts_by_its_content_and_settings_by_whether_they_change_actions(tmp_path):
    first = fake_checkpoint(tmp_path / "a")
    same_elsewhere = fake_checkpoint(tmp_path / "copy" / "b")
    retrained = fake_checkpoint(tmp_path / "c", weights=b"other weights")
    base = PiConfig(checkpoint=str(first))
    reference = identity_hash(base, first)
    assert identity_hash(PiConfig(checkpoint=str(same_elsewhere)), same_elsewhere) == reference
    assert identity_hash(PiConfig(checkpoint=str(retrained)), retrained) != reference
    for changes_actions in ({"replan_steps": 4}, {"max_steps": 30}, {"max_batch": 4}):
        assert identity_hash(PiConfig(checkpoint=str(first), **changes_actions), first) != reference
    for how_it_runs in (
        {"device": "cpu"},
        {"python": "/x/python"},
        {"request_timeout_s": 5.0},
        {"startup_timeout_s": 1},
    ):
        assert identity_hash(PiConfig(checkpoint=str(first), **how_it_runs), first) == reference


def test_against_a_running_server_its_own_word_on_the_model_is_the_identity(tmp_path):
    server, url = start_openpi_server(tmp_path)  # openpi's server says nothing: the given name counts
    try:
        named = [load("pi05", PiConfig(server=url, checkpoint=name, connect_retries=0)) for name in ("a", "b")]
        try:
            assert [p.identity for p in named] == [
                {"checkpoint": "a", "max_batch": 1, "model_stack": "unreported"},
                {"checkpoint": "b", "max_batch": 1, "model_stack": "unreported"},
            ]
        finally:
            for p in named:
                p.close()
    finally:
        server.stop()


@pytest.mark.sim
@pytest.mark.parametrize(
    "settings, message",
    [
        ([], "model=pi05 needs model.checkpoint=DIR"),
        (["model.server=ws://127.0.0.1:9"], "also needs model.checkpoint=NAME"),
        (["model.checkpoint={pi0}"], "is a pi0 checkpoint: use model=pi0, not model=pi05"),
        (["model.checkpoint={missing}"], "no checkpoint folder at"),
        (["model.checkpoint={pi05}", "model.python=/no/such/python"], "no model environment at /no/such/python"),
        (["model.checkpoint={pi05}", "model.python={bare_python}"], "cannot run the pi0 server"),
        (["model.checkpoint={pi05}", "model.device=gpu"], "model.device must be cpu, cuda, cuda:N or auto"),
        (["model.checkpoint={pi05}", "model.replan_steps=0"], "model.replan_steps must be >= 1, got 0"),
        (["model.checkpoint={pi05}", "model.max_batch=0"], "model.max_batch must be >= 1"),
    ],
)
def test_user_mistakes_are_one_line_and_exit_code_2(tmp_path, settings, message):
    import subprocess

    folders = {"pi0": fake_checkpoint(tmp_path / "pi0", "pi0"), "pi05": fake_checkpoint(tmp_path / "pi05")}
    bare_python = Path(sys.base_prefix) / "bin" / "python3"  # this interpreter without the venv: no plugin
    values = {**folders, "missing": tmp_path / "nope", "bare_python": bare_python}
    args = ["model=pi05", "suite=physical", "level=L1", "run.libero_suites=[libero_spatial]", "run.progress=false"]
    args += [f"run.out={tmp_path / 'results'}", *[s.format(**values) for s in settings]]
    out = subprocess.run(
        [sys.executable, "-m", "conflictbench.cli", *args], capture_output=True, text=True, timeout=300
    )
    assert out.returncode == 2, out.stderr[-2000:]
    last = out.stderr.strip().splitlines()[-1]
    assert last.startswith("conflictbench: error: ") and message in last, last
    assert "Traceback" not in out.stderr
