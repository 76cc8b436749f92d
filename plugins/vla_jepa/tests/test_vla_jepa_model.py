"""A tiny random-weight LeRobot VLA-JEPA checkpoint behind our server: its sampling is LeRobot's, row by row;
what the client executes is what LeRobot's own postprocessor gives; ``model.checkpoint=DIR`` plays real episodes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from jepa_model_env import TESTS, VLA_JEPA, model_env, needs_model_env, run_in_model_env

from conflictbench.testing import camera_observation, run_cli
from conflictbench.testing.plugin_tests import check_served_identity, played_records
from conflictbench_vla_jepa.checkpoints import fingerprint
from conflictbench_vla_jepa.client import VlaJepaConfig, load

MAX_BATCH = 2


def direct(checkpoint: Path, payloads: list[dict], tmp_path: Path) -> dict[str, np.ndarray]:
    """jepa_direct.py's results for these payloads' rows (one row each)."""
    requests, out = tmp_path / "requests.npz", tmp_path / "direct.npz"
    np.savez(
        requests,
        images=np.stack([p["batch_images"][0][0] for p in payloads]),
        wrist_images=np.stack([p["batch_images"][0][1] for p in payloads]),
        states=np.stack([np.asarray(p["state"][0]).reshape(8) for p in payloads]),
        seeds=np.array([p["conflictbench/noise_seed"] for p in payloads], dtype=np.uint64),
        instructions=json.dumps([p["instructions"][0] for p in payloads]),
    )
    run_in_model_env([str(TESTS / "jepa_direct.py"), str(checkpoint), str(requests), str(MAX_BATCH), str(out)],
                     checkpoint)  # fmt: skip
    return dict(np.load(out))


@needs_model_env
def test_served_actions_are_lerobots_own_sampling_and_postprocessing(tiny_checkpoint, tmp_path, monkeypatch):
    VLA_JEPA.use(monkeypatch, tiny_checkpoint)
    policy = load("vla-jepa", VlaJepaConfig(checkpoint=str(tiny_checkpoint), max_batch=MAX_BATCH, device="cpu"))
    try:
        policy.start()
        assert policy.metadata["chunk_length"] == 7 and policy.chunk_length == 7
        check_served_identity(policy, fingerprint(tiny_checkpoint), MAX_BATCH)
        observations = [camera_observation(step, text) for step, text in [(0, "pick up the bowl"), (5, "open it")]]
        served = [policy.act(obs) for obs in observations]
        payloads = [policy.encode(obs)["payload"] for obs in observations]
    finally:
        policy.close()
    results = direct(tiny_checkpoint, payloads, tmp_path)
    # Our per-row noise is exactly LeRobot's own draw for that row alone, seeded with its seed; and a row's chunk
    # is the same alone, in the server's fixed-shape call and beside another row with a longer prompt.
    np.testing.assert_array_equal(results["backend_alone"], results["lerobot_alone"])
    np.testing.assert_array_equal(results["backend_served"], results["backend_alone"])
    np.testing.assert_array_equal(results["backend_in_company"], results["backend_alone"])
    for actions, executed in zip(served, results["executed"], strict=True):
        assert actions.shape == (7, 7)
        np.testing.assert_allclose(actions, executed, atol=1e-5)  # the client's un-normalizing is LeRobot's
        assert set(actions[:, 6]) <= {-1.0, 1.0}
    assert not np.allclose(served[0], served[1])


@pytest.mark.e2e
@needs_model_env
@pytest.mark.sim
def test_a_run_with_a_checkpoint_starts_the_server_and_plays_real_episodes(tiny_checkpoint, tmp_path):
    settings = ["model=vla-jepa", f"model.checkpoint={tiny_checkpoint}", "model.max_steps=14", "model.device=cpu"]
    out = run_cli(tmp_path, *settings, env=model_env(tiny_checkpoint))
    records = played_records(tmp_path, out, 14)
    assert all(set(np.asarray(r.raw_actions)[:, 6]) <= {-1.0, 1.0} for r in records)
