"""The LeRobot backend: checkpoint checks (pure Python) and, in the model environment, tiny pi0 / pi0.5 /
pi0-FAST checkpoints served batched, one by one, and by LeRobot directly (``tests/tiny/direct.py``).

The model-environment results come from two kinds of real processes, run once per session side by side:
``tests/tiny/run_backend.py`` (our backend, every checkpoint, the same requests batched and one by one) and
``tests/tiny/direct.py`` (LeRobot alone, one request per call, for each checkpoint).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from tiny_fixtures import TINY_DIR, needs_model_env, run_model_processes

from conflictbench_pi0.backend import CheckpointError, checkpoint_type, load_backend
from conflictbench_pi0.protocol import IMAGE, NOISE_SEED, PROMPT, STATE, WRIST_IMAGE, packb

#: Batched and single calls differ only by float32 rounding in differently blocked matmuls (measured: at
#: most 9.5e-7 on these tiny models, 0 for FAST); a real dependence on batch company would be orders larger.
BATCH_TOLERANCE = 1e-5
#: Changing an input must move the actions by more than rounding (measured: the smallest such change, pi0.5's
#: to the state, is 5e-3; seeds move pi0 / pi0.5 actions by 4-8, inputs move FAST tokens' actions by 0.5-3).
CHANGED = 1e-3
CHUNK_LENGTHS = {"pi0": 50, "pi05": 10, "pi0-fast": 10, "pi0-fast-sampled": 10}


# --------------------------------------------------------------------------------------------------------
# Checkpoint checks: pure Python, before any torch import


def write_checkpoint(folder: Path, config: dict, files=("model.safetensors",)) -> Path:
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps(config))
    for name in files:
        (folder / name).write_text("{}")
    return folder


def pi_config(cameras=("observation.images.image", "observation.images.image2"), state_dim=8, kind="pi05"):
    features = {name: {"type": "VISUAL", "shape": [3, 224, 224]} for name in cameras}
    features["observation.state"] = {"type": "STATE", "shape": [state_dim]}
    return {"type": kind, "input_features": features, "output_features": {"action": {"type": "ACTION", "shape": [7]}}}


COMPLETE = ("model.safetensors", "policy_preprocessor.json", "policy_postprocessor.json")


def test_checkpoint_type_of_a_missing_folder(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint folder"):
        checkpoint_type(tmp_path / "absent")


def test_checkpoint_type_without_config(tmp_path):
    (tmp_path / "model.safetensors").write_text("")
    with pytest.raises(CheckpointError, match=r"no config\.json"):
        checkpoint_type(tmp_path)


def test_checkpoint_type_of_another_policy(tmp_path):
    folder = write_checkpoint(tmp_path / "act", {"type": "act"})
    with pytest.raises(CheckpointError, match="holds a act policy"):
        checkpoint_type(folder)


def test_checkpoint_type_without_weights(tmp_path):
    folder = write_checkpoint(tmp_path / "pi0", {"type": "pi0"}, files=())
    with pytest.raises(CheckpointError, match=r"no model\.safetensors"):
        checkpoint_type(folder)


@pytest.mark.parametrize("kind", ["pi0", "pi05", "pi0_fast"])
def test_checkpoint_type_reads_the_config_type(tmp_path, kind):
    assert checkpoint_type(write_checkpoint(tmp_path / kind, {"type": kind})) == kind


# load_backend refuses these from config.json alone, so they need no model environment either.


def test_load_refuses_one_camera(tmp_path):
    folder = write_checkpoint(tmp_path / "one", pi_config(cameras=["observation.images.image"]), COMPLETE)
    with pytest.raises(CheckpointError, match=r"takes 1 camera image\(s\) \(observation\.images\.image\)"):
        load_backend(folder)


def test_load_refuses_three_cameras(tmp_path):
    cameras = ["observation.images.a", "observation.images.b", "observation.images.c"]
    folder = write_checkpoint(tmp_path / "three", pi_config(cameras=cameras), COMPLETE)
    with pytest.raises(CheckpointError, match="takes 3 camera image"):
        load_backend(folder)


def test_load_refuses_another_state_size(tmp_path):
    folder = write_checkpoint(tmp_path / "state", pi_config(state_dim=14), COMPLETE)
    with pytest.raises(CheckpointError, match=r"state of shape \[14\]"):
        load_backend(folder)


def test_load_refuses_a_checkpoint_without_normalization_stats(tmp_path):
    folder = write_checkpoint(tmp_path / "old", pi_config(), ("model.safetensors",))
    with pytest.raises(CheckpointError, match=r"no policy_preprocessor\.json"):
        load_backend(folder)


# --------------------------------------------------------------------------------------------------------
# Tiny checkpoints in the model environment


def random_image(rng) -> np.ndarray:
    return rng.integers(0, 256, (224, 224, 3), dtype=np.uint8)


def make_requests() -> dict[str, dict]:
    """A base request and variants that each change one thing (named so tests can pick them)."""
    rng = np.random.default_rng(7)
    base = {
        IMAGE: random_image(rng),
        WRIST_IMAGE: random_image(rng),
        STATE: np.array([-0.05, 0.02, 1.05, 3.1, -0.2, 0.05, 0.03, -0.03]),
        PROMPT: "put the black bowl on the plate",
        NOISE_SEED: 11,
    }
    variants = {
        "base": base,
        "other seed": {**base, NOISE_SEED: 12},
        "other image": {**base, IMAGE: random_image(rng)},
        "other wrist image": {**base, WRIST_IMAGE: random_image(rng)},
        "other state": {**base, STATE: base[STATE] + np.array([0.1, -0.1, 0.05, 0.3, 0.3, -0.3, 0.0, 0.0])},
        "other prompt": {**base, PROMPT: "open the top drawer and put the bowl inside"},
        "seed 0": {**base, NOISE_SEED: 0},
        "no seed": {key: value for key, value in base.items() if key != NOISE_SEED},
        "base again": dict(base),
    }
    return variants


REQUEST_NAMES = list(make_requests())


def index(name: str) -> int:
    return REQUEST_NAMES.index(name)


@pytest.fixture(scope="session")
def tiny_results(tiny_checkpoints, tiny_env, tmp_path_factory) -> dict[str, dict]:
    """Per checkpoint: backend ``batch`` and ``singles``, ``direct`` actions, and the backend's ``report``."""
    work = tmp_path_factory.mktemp("tiny-backend")
    checkpoints = dict(tiny_checkpoints)
    # pi0-FAST sampling tokens (temperature > 0): the same weights with the sampled decoding path.
    sampled = work / "pi0-fast-sampled"
    shutil.copytree(tiny_checkpoints["pi0-fast"], sampled)
    config = json.loads((sampled / "config.json").read_text())
    (sampled / "config.json").write_text(json.dumps({**config, "temperature": 0.7}))
    checkpoints["pi0-fast-sampled"] = sampled
    # A pi0 folder holding pi0.5 weights: LeRobot only prints that they do not fit.
    mismatched = work / "pi0-with-pi05-weights"
    shutil.copytree(tiny_checkpoints["pi0"], mismatched)
    shutil.copy(tiny_checkpoints["pi05"] / "model.safetensors", mismatched / "model.safetensors")

    requests_file = work / "requests.msgpack"
    requests_file.write_bytes(packb(list(make_requests().values())))
    served = [f"{name}={folder}" for name, folder in checkpoints.items()] + [f"mismatched={mismatched}"]
    commands = {
        "backend": [str(TINY_DIR / "run_backend.py"), "--requests", str(requests_file), "--out-dir", str(work), *served]
    }
    for name, folder in checkpoints.items():
        commands[f"direct {name}"] = [
            str(TINY_DIR / "direct.py"), "--checkpoint", str(folder), "--requests", str(requests_file),
            "--out", str(work / f"direct-{name}.npz"),
        ]  # fmt: skip
    run_model_processes(commands, tiny_env, timeout_s=600)

    results = {}
    for name in [*checkpoints, "mismatched"]:
        result = {"report": json.loads((work / f"{name}.json").read_text())}
        if (work / f"{name}.npz").exists():
            result.update(np.load(work / f"{name}.npz"))
            result["direct"] = np.load(work / f"direct-{name}.npz")["actions"]
        results[name] = result
    return results


SERVED = ["pi0", "pi05", "pi0-fast", "pi0-fast-sampled"]
#: Flow matching (pi0, pi0.5) and sampled FAST tokens draw on the seed; greedy FAST decoding does not.
SEEDED = ["pi0", "pi05", "pi0-fast-sampled"]


def largest_change(actions: np.ndarray, first: str, second: str) -> float:
    return float(np.abs(actions[index(first)] - actions[index(second)]).max())


@needs_model_env
@pytest.mark.parametrize("name", SERVED)
def test_actions_are_chunks_of_7d_float32_with_their_metadata(tiny_results, name):
    result = tiny_results[name]
    for actions in (result["batch"], result["singles"]):
        assert actions.dtype == np.float32
        assert actions.shape == (len(REQUEST_NAMES), CHUNK_LENGTHS[name], 7)
        assert np.isfinite(actions).all()
    metadata = result["report"]["metadata"]
    assert metadata["policy_type"] == {"pi0-fast-sampled": "pi0_fast", "pi0-fast": "pi0_fast"}.get(name, name)
    assert metadata["action_horizon"] == CHUNK_LENGTHS[name]
    assert metadata["action_dim"] == 7
    assert metadata["image_keys"] == ["observation.images.image", "observation.images.image2"]
    assert metadata["lerobot_version"] == "0.6.1"


@needs_model_env
@pytest.mark.parametrize("name", SERVED)
def test_a_batch_gives_what_single_calls_give(tiny_results, name):
    result = tiny_results[name]
    assert np.abs(result["batch"] - result["singles"]).max() <= BATCH_TOLERANCE


@needs_model_env
@pytest.mark.parametrize("name", SERVED)
def test_the_same_request_twice_in_a_batch_gives_the_same_actions(tiny_results, name):
    assert largest_change(tiny_results[name]["batch"], "base", "base again") <= BATCH_TOLERANCE


@needs_model_env
@pytest.mark.parametrize("name", SERVED)
@pytest.mark.parametrize("variant", ["other image", "other wrist image", "other state", "other prompt"])
def test_actions_follow_the_observation(tiny_results, name, variant):
    assert largest_change(tiny_results[name]["singles"], "base", variant) > CHANGED


@needs_model_env
@pytest.mark.parametrize("name", SEEDED)
def test_actions_follow_the_noise_seed(tiny_results, name):
    assert largest_change(tiny_results[name]["singles"], "base", "other seed") > CHANGED


@needs_model_env
def test_greedy_fast_decoding_ignores_the_seed(tiny_results):
    assert largest_change(tiny_results["pi0-fast"]["singles"], "base", "other seed") == 0.0


@needs_model_env
@pytest.mark.parametrize("name", SEEDED)
def test_a_request_without_seed_uses_seed_0(tiny_results, name):
    assert largest_change(tiny_results[name]["singles"], "no seed", "seed 0") == 0.0
    assert largest_change(tiny_results[name]["singles"], "no seed", "base") > CHANGED


@needs_model_env
@pytest.mark.parametrize("name", SERVED)
def test_lerobot_called_directly_agrees_with_the_backend(tiny_results, name):
    result = tiny_results[name]
    assert result["direct"].shape == result["singles"].shape
    assert np.abs(result["direct"] - result["batch"]).max() <= BATCH_TOLERANCE


@needs_model_env
@pytest.mark.parametrize("name", SERVED)
def test_lerobots_letterbox_leaves_the_clients_224_px_images_alone(tiny_results, name):
    report = tiny_results[name]["report"]
    assert report["image_resolution"] == [224, 224]
    assert report["letterbox_change"] == 0.0


@needs_model_env
def test_weights_that_do_not_fit_are_refused(tiny_results):
    error = tiny_results["mismatched"]["report"]["error"]
    assert "does not fit the pi0 model" in error
