"""A tiny stand-in OpenVLA checkpoint (its own model code, loaded with ``trust_remote_code``) behind our server:
the served action is the checkpoint's own ``predict_action``, which agrees with the plugin's pinned de-tokenization;
``model.checkpoint=DIR`` plays real episodes; the serve command's mistakes are one line."""

from __future__ import annotations

import http.client
import json
import shutil
from pathlib import Path

import json_numpy
import numpy as np
import pytest
from openvla_model_env import OPENVLA, TESTS, model_env, needs_model_env, run_in_model_env, start_server

from conflictbench import InfrastructureError, UserError
from conflictbench.hosting.openvla_family import env_gripper, unnormalize
from conflictbench.testing import camera_observation, run_cli
from conflictbench.testing.plugin_tests import check_served_identity, played_records
from conflictbench_openvla.checkpoints import fingerprint
from conflictbench_openvla.client import OftConfig, OpenVlaConfig, load
from conflictbench_openvla.processing import detokenize


def direct(checkpoint: Path, requests: list[dict], tmp_path: Path) -> dict[str, np.ndarray]:
    path, out = tmp_path / "requests.npz", tmp_path / "direct.npz"
    np.savez(path, images=np.stack([r["image"] for r in requests]), keys=np.array([r["unnorm_key"] for r in requests]),
             instructions=json.dumps([r["instruction"] for r in requests]))  # fmt: skip
    run_in_model_env([str(TESTS / "openvla_direct.py"), str(checkpoint), str(path), str(out)], checkpoint)
    return dict(np.load(out))


@needs_model_env
def test_served_actions_are_the_checkpoints_own_predict_action(tiny_checkpoint, tmp_path, monkeypatch):
    OPENVLA.use(monkeypatch, tiny_checkpoint)
    policy = load("openvla", OpenVlaConfig(checkpoint=str(tiny_checkpoint), device="cpu"))
    try:
        policy.start()
        check_served_identity(policy, fingerprint(tiny_checkpoint), 2)
        assert policy.metadata["unnorm_keys"] == ["libero_10", "libero_goal", "libero_object", "libero_spatial"]
        observations = [camera_observation(0, "Pick up the bowl", suite="libero_goal"),
                        camera_observation(3, "open the drawer", suite="libero_10", stream=1)]  # fmt: skip
        served = [policy.act(obs) for obs in observations]
        requests = [policy.encode(obs) for obs in observations]
    finally:
        policy.close()
    results = direct(tiny_checkpoint, requests, tmp_path)
    statistics = json.loads((tiny_checkpoint / "dataset_statistics.json").read_text())
    for i, request in enumerate(requests):
        np.testing.assert_array_equal(served[i], env_gripper(results["actions"][i]))
        pinned = unnormalize(
            detokenize(results["tokens"][i], vocab_size=32000), statistics[request["unnorm_key"]]["action"]
        )
        np.testing.assert_allclose(results["actions"][i], pinned, rtol=0, atol=1e-12)  # upstream's reading, restated
    assert not np.array_equal(served[0], served[1])


@needs_model_env
def test_a_key_the_checkpoint_lacks_fails_that_request_naming_the_keys_it_has(tiny_checkpoint, monkeypatch):
    OPENVLA.use(monkeypatch, tiny_checkpoint)
    policy = load("openvla", OpenVlaConfig(checkpoint=str(tiny_checkpoint), device="cpu", unnorm_key="suite_no_noops"))
    try:
        policy.start()
        [failed] = policy.act_batch([camera_observation(0)])
        assert isinstance(failed, InfrastructureError)
        assert "no statistics 'libero_goal_no_noops' (it has: libero_10, libero_goal" in str(failed)
    finally:
        policy.close()


@needs_model_env
def test_our_openvla_server_is_refused_for_openvla_oft(tiny_checkpoint, tmp_path):
    server, port = start_server(tiny_checkpoint, tmp_path)
    try:
        with pytest.raises(UserError, match="hosts a openvla policy, not openvla-oft"):
            load("openvla-oft", OftConfig(server=f"http://127.0.0.1:{port}", checkpoint="x", connect_retries=0))
    finally:
        server.stop()


@needs_model_env
def test_a_double_encoded_request_is_answered_double_encoded_as_deploy_py_does(tiny_checkpoint, tmp_path):
    server, port = start_server(tiny_checkpoint, tmp_path)
    try:
        image = camera_observation(1).agentview_image[:224, :224]
        payload = {"image": image, "instruction": "put it down", "unnorm_key": "libero_goal"}
        replies = []
        for body in (json_numpy.dumps(payload), json.dumps({"encoded": json_numpy.dumps(payload)})):
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
            conn.request("POST", "/act", body, {"Content-Type": "application/json"})
            response = conn.getresponse()
            assert response.status == 200
            replies.append(json.loads(response.read()))
            conn.close()
        plain, encoded = replies
        assert isinstance(encoded, str)  # a JSON string holding the json-numpy text
        np.testing.assert_array_equal(json_numpy.loads(encoded), json_numpy.loads(json.dumps(plain)))
    finally:
        server.stop()


@pytest.mark.e2e
@needs_model_env
def test_model_checkpoint_dir_plays_real_episodes(tiny_checkpoint, tmp_path):
    out = run_cli(tmp_path, "model=openvla", f"model.checkpoint={tiny_checkpoint}", "model.device=cpu",
                  "model.max_steps=6", env=model_env(tiny_checkpoint))  # fmt: skip
    records = played_records(tmp_path, out, 6)
    assert len({r.policy for r in records}) == 1
    reference, conflict = sorted(records, key=lambda r: r.case_id is not None)
    assert not np.array_equal(reference.raw_actions, conflict.raw_actions)  # each text reached the model


@needs_model_env
@pytest.mark.parametrize(
    "change, message",
    [
        ("missing", "no checkpoint folder at"),
        ("no_auto_map", "has no auto_map entry for AutoModelForVision2Seq"),
        ("no_code", "lacks modeling_standin.py, the model code its config.json names"),
        ("old_transformers", "was written with transformers 4.31.0; this environment has 4.40.1"),
        ("oft", "served by OFT's own vla-scripts/deploy.py"),
    ],
)
def test_serve_refuses_what_it_cannot_serve_in_one_line(tiny_checkpoint, tmp_path, change, message):
    folder = tmp_path / "checkpoint"
    if change != "missing":
        shutil.copytree(tiny_checkpoint, folder)
    config_path = folder / "config.json"
    if change in ("no_auto_map", "old_transformers"):
        config = json.loads(config_path.read_text())
        if change == "no_auto_map":
            del config["auto_map"]
        else:
            config["transformers_version"] = "4.31.0"
        config_path.write_text(json.dumps(config))
    if change == "no_code":
        (folder / "modeling_standin.py").unlink()
    policy = "openvla-oft" if change == "oft" else "openvla"
    done = run_in_model_env(["-m", "conflictbench_serving", policy, "--checkpoint", str(folder),
                             "--port", "0"], tiny_checkpoint, check=False)  # fmt: skip
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and message in lines[-1] and "Traceback" not in done.stderr, done.stderr[-2000:]
