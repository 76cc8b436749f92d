"""A tiny checkpoint for a stand-in UniVLA checkout behind our server: UniVLA's code read by file from UNIVLA_CODE;
each query's tokens and chunk are the checkpoint's own, seeded per request; the client's loop over them is UniVLA's;
``model.checkpoint=DIR`` plays real episodes; what cannot be served is one line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from univla_model_env import TESTS, UNIVLA, model_env, needs_model_env, run_in_model_env

from conflictbench import UserError
from conflictbench.hosting.openvla_family import env_gripper, unnormalize
from conflictbench.testing import camera_observation, run_cli
from conflictbench.testing.plugin_tests import check_served_identity, played_records
from conflictbench_univla.checkpoints import fingerprint
from conflictbench_univla.client import UnivlaConfig, load
from conflictbench_univla.processing import TemporalEnsemble, history_text, prompt


def direct(checkpoint: Path, requests: list[dict], tmp_path: Path) -> dict[str, np.ndarray]:
    path, out = tmp_path / "requests.npz", tmp_path / "direct.npz"
    prompts = [prompt(r["instruction"], r["history"]) for r in requests]
    np.savez(path, images=np.stack([r["image"] for r in requests]), prompts=json.dumps(prompts),
             seeds=np.array([r["conflictbench/noise_seed"] for r in requests], dtype=np.uint64),
             keys=np.array([r["unnorm_key"] for r in requests]))  # fmt: skip
    run_in_model_env([str(TESTS / "univla_direct.py"), str(checkpoint), str(path), str(out)])
    return dict(np.load(out))


@needs_model_env
def test_each_query_is_the_checkpoints_own_seeded_sample_and_the_loop_is_univlas(
    tiny_checkpoint, tmp_path, monkeypatch
):
    UNIVLA.use(monkeypatch)
    policy = load("univla", UnivlaConfig(checkpoint=str(tiny_checkpoint), device="cpu"))
    observations = [camera_observation(step, "Put the bowl on the plate") for step in range(4)]
    try:
        policy.start()
        check_served_identity(policy, fingerprint(tiny_checkpoint), 2)
        assert policy.window == 12
        requests, served = [], []
        for obs in observations:
            requests.append(policy.encode(obs))
            served.append(policy.act(obs))
    finally:
        policy.close()
    results = direct(tiny_checkpoint, requests, tmp_path)
    assert requests[0]["history"] == ""
    for k in range(1, len(requests)):  # the next prompt carries exactly the tokens the last query generated
        assert requests[k]["history"] == history_text(results["tokens"][k - 1])
    statistics = json.loads((tiny_checkpoint / "dataset_statistics.json").read_text())["libero_goal"]["action"]
    ensemble = TemporalEnsemble(12)
    for k, action in enumerate(served):
        expected = env_gripper(unnormalize(ensemble.add(results["chunks"][k]), statistics))
        np.testing.assert_array_equal(action, expected)
    assert len({tuple(row) for row in np.array(served)[:, :3]}) == len(served)


@pytest.mark.e2e
@needs_model_env
def test_model_checkpoint_dir_plays_real_episodes(tiny_checkpoint, tmp_path):
    out = run_cli(tmp_path, "model=univla", f"model.checkpoint={tiny_checkpoint}", "model.device=cpu",
                  "model.max_steps=6", env=model_env())  # fmt: skip
    reference, conflict = played_records(tmp_path, out, 6)
    assert not np.array_equal(reference.raw_actions, conflict.raw_actions)


@needs_model_env
def test_without_univla_code_the_run_says_so_before_starting_anything(tiny_checkpoint, monkeypatch):
    monkeypatch.delenv("UNIVLA_CODE", raising=False)
    with pytest.raises(UserError, match="set UNIVLA_CODE to a checkout of OpenDriveLab/UniVLA"):
        load("univla", UnivlaConfig(checkpoint=str(tiny_checkpoint)))
    monkeypatch.setenv("UNIVLA_CODE", str(tiny_checkpoint))
    with pytest.raises(UserError, match="is not a UniVLA checkout .no prismatic/extern/hf/configuration_prismatic.py"):
        load("univla", UnivlaConfig(checkpoint=str(tiny_checkpoint)))


@needs_model_env
@pytest.mark.parametrize(
    "change, message",
    [
        ("missing", "no checkpoint folder at"),
        ("no_decoder", "lacks action_decoder.pt, the action decoder's weights"),
        ("no_code", "set UNIVLA_CODE to a checkout"),
        ("bad_decoder", "is not an ActionDecoderHead's state dict"),
        ("incomplete_decoder", "does not fit UniVLA's ActionDecoderHead"),
    ],
)
def test_serve_refuses_what_it_cannot_serve_in_one_line(tiny_checkpoint, tmp_path, change, message):
    folder = tmp_path / "checkpoint"
    if change != "missing":
        shutil.copytree(tiny_checkpoint, folder)
    if change == "no_decoder":
        (folder / "action_decoder.pt").unlink()
    if change == "incomplete_decoder":  # another module's weights: a key of UniVLA's head missing
        drop = "import sys, torch; p = sys.argv[1]; s = torch.load(p); del s['visual_pool.latents']; torch.save(s, p)"
        run_in_model_env(["-c", drop, str(folder / "action_decoder.pt")])
    if change == "bad_decoder":
        (folder / "action_decoder.pt").write_bytes((folder / "dataset_statistics.json").read_bytes())
    env = model_env()
    if change == "no_code":
        del env["UNIVLA_CODE"]
    argv = ["-m", "conflictbench_serving", "univla", "--checkpoint", str(folder), "--port", "0"]
    done = run_in_model_env(argv, check=False, env=env)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and message in lines[-1] and "Traceback" not in done.stderr, done.stderr[-2000:]
