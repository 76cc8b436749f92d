"""A tiny random-weight LeRobot GR00T N1.7 checkpoint behind our server: its sampling and processing are
LeRobot's, row by row; what the unchanged GR00T client executes is LeRobot's chunk; ``model.checkpoint=DIR``
plays real episodes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from groot_model_env import GR00T, TESTS, model_env, needs_model_env, run_in_model_env

from conflictbench.testing import camera_observation, run_cli
from conflictbench.testing.plugin_tests import check_served_identity, played_records
from conflictbench_gr00t.checkpoints import fingerprint
from conflictbench_gr00t.client import Gr00tConfig, load


@needs_model_env
def test_served_actions_are_lerobots_own_sampling_and_processing(tiny_groot_checkpoint, tmp_path, monkeypatch):
    GR00T.use(monkeypatch, tiny_groot_checkpoint)
    policy = load("gr00t", Gr00tConfig(checkpoint=str(tiny_groot_checkpoint), max_batch=2, device="cpu"))
    try:
        policy.start()
        check_served_identity(policy, fingerprint(tiny_groot_checkpoint), 2)
        observations = [camera_observation(step, text) for step, text in [(0, "pick up the bowl"), (7, "open it")]]
        served = [policy.act(obs) for obs in observations]
        requests = [policy.encode(obs)["data"] for obs in observations]
    finally:
        policy.close()
    arrays = {f"obs{i}/{key}": value for i, request in enumerate(requests)
              for key, value in request["observation"].items() if isinstance(value, np.ndarray)}  # fmt: skip
    texts = [request["observation"]["annotation.human.action.task_description"][0] for request in requests]
    seeds = np.array([request["options"]["conflictbench/noise_seed"] for request in requests], dtype=np.uint64)
    states = np.stack([obs.state for obs in observations])
    np.savez(tmp_path / "requests.npz", texts=json.dumps(texts), seeds=seeds, states=states, **arrays)
    run_in_model_env([str(TESTS / "groot_direct.py"), str(tiny_groot_checkpoint), str(tmp_path / "requests.npz"),
                      str(tmp_path / "direct.npz")], tiny_groot_checkpoint)  # fmt: skip
    direct = np.load(tmp_path / "direct.npz")
    # Our per-row noise, one-row passes and key mapping are exactly LeRobot's own sampling of that row alone.
    np.testing.assert_array_equal(direct["backend"], direct["lerobot"])
    np.testing.assert_array_equal(
        direct["in_company_x"], direct["lerobot"][:, :, 0]
    )  # left-padded prompts: not batched
    for actions, chunk in zip(served, direct["lerobot"], strict=True):
        assert actions.shape == (8, 7)  # GR00T's client executes 8 of each chunk
        np.testing.assert_allclose(actions[:, :6], chunk[:8, :6], atol=1e-6)
        assert actions[:, 6].tolist() == np.sign(chunk[:8, 6]).tolist()  # LeRobot's gripper sign, through [0, 1]
    assert not np.allclose(served[0], served[1])


@pytest.mark.e2e
@needs_model_env
@pytest.mark.sim
def test_a_run_with_a_checkpoint_starts_the_server_and_plays_real_episodes(tiny_groot_checkpoint, tmp_path: Path):
    settings = ["model=gr00t", f"model.checkpoint={tiny_groot_checkpoint}", "model.max_steps=16", "model.device=cpu"]
    out = run_cli(tmp_path, *settings, env=model_env(tiny_groot_checkpoint))
    played_records(tmp_path, out, 16)  # both episodes played 16 steps without an error
