"""``conflictbench model=lerobot model.checkpoint=DIR`` on real LIBERO episodes: the run starts our server in the model
environment and plays each tested type's episodes (their warm-up, control mode and each episode's own text and seed
checked here; what the policy receives at every step is the oracle test's), and a checkpoint LeRobot cannot load, or
one LIBERO cannot feed, is one line and exit code 2 before any episode."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from lerobot_fixtures import LEROBOT, TINY_TYPES, needs_model_env

from conflictbench.testing import run_cli
from conflictbench.testing.plugin_tests import played_records

pytestmark = [pytest.mark.sim, pytest.mark.e2e]
STEPS = 12
#: The tested type whose first action is the same in a conflict and its reference: ACT reads no text and samples
#: nothing. The others read the text (SmolVLA, π0.5, X-VLA, Multi-task DiT) or sample with each episode's own seed
#: (Diffusion).
BLIND_AND_DETERMINISTIC = {"act"}


@needs_model_env
@pytest.mark.parametrize("policy_type", TINY_TYPES)
def test_a_started_server_plays_lerobot_evals_episode_with_each_instruction(
    policy_type, tiny_lerobot_checkpoints, tmp_path
):
    checkpoint = tiny_lerobot_checkpoints[policy_type]
    env = {**LEROBOT.env(checkpoint), "MUJOCO_GL": "egl"}
    mode = "absolute" if policy_type == "xvla" else "relative"  # as X-VLA's LIBERO checkpoints are played
    out = run_cli(tmp_path, "model=lerobot", f"model.checkpoint={checkpoint}", "model.device=cpu",
                  f"model.control_mode={mode}", env=env, max_steps=STEPS)  # fmt: skip
    assert f"plays a LeRobot {policy_type} policy" in out.stderr and "untested" not in out.stderr
    reference, conflict = played_records(tmp_path, out, STEPS)
    for record in (reference, conflict):
        assert record.warmup_steps == 10 and record.actions.shape == (STEPS, 7) and record.control_mode == mode
        assert np.all(np.isfinite(record.actions)) and np.linalg.norm(record.eef_pos[-1] - record.eef_pos[0]) > 1e-4
    # Each episode's own text and seed reached the model: where the type reads or draws them, the first actions differ.
    assert np.array_equal(reference.actions[0], conflict.actions[0]) is (policy_type in BLIND_AND_DETERMINISTIC)
    server_log = next((tmp_path / "results" / "logs" / "servers").glob("lerobot-*.log")).read_text()
    assert "serving lerobot from" in server_log


@needs_model_env
@pytest.mark.parametrize("policy_type", ["act", "pi05"])
def test_a_checkpoint_lerobot_cannot_load_is_one_line_and_exit_code_2(policy_type, tiny_lerobot_checkpoints, tmp_path):
    """ACT's loader raises on a damaged weights file; π0.5's prints and goes on with random weights: both refused."""
    broken = tmp_path / "broken"
    shutil.copytree(tiny_lerobot_checkpoints[policy_type], broken)
    (broken / "model.safetensors").write_bytes(b"not a safetensors file")
    out = run_cli(tmp_path, "model=lerobot", f"model.checkpoint={broken}", "model.device=cpu",
                  env=LEROBOT.env(broken), max_steps=STEPS)  # fmt: skip
    assert out.returncode == 2, out.stderr[-3000:]
    last = out.stderr.strip().splitlines()[-1]
    said = {"act": "LeRobot cannot load", "pi05": "model.safetensors does not fit the pi05 model"}[policy_type]
    assert last.startswith("conflictbench: error: conflictbench-serve: ") and said in last and str(broken) in last
    assert not (tmp_path / "results" / "episodes").exists() or not any((tmp_path / "results").rglob("*.parquet"))


def test_a_checkpoint_whose_inputs_libero_cannot_give_is_refused_before_any_server(tmp_path):
    folder = tmp_path / "three-cameras"
    folder.mkdir()
    inputs = {f"observation.images.{c}": {"type": "VISUAL", "shape": [3, 224, 224]} for c in ("top", "left", "right")}
    config = {"type": "act", "input_features": inputs, "output_features": {"action": {"type": "ACTION", "shape": [7]}}}
    (folder / "config.json").write_text(json.dumps(config))
    (folder / "model.safetensors").write_bytes(b"")
    out = run_cli(tmp_path, "model=lerobot", f"model.checkpoint={folder}", max_steps=STEPS)
    last = out.stderr.strip().splitlines()[-1]
    assert out.returncode == 2 and last.startswith("conflictbench: error: ") and "starting" not in out.stderr
    assert "takes the cameras observation.images.left, observation.images.right, observation.images.top" in last
    assert "LIBERO gives observation.images.image, observation.images.image2" in last


def test_an_untested_policy_type_loads_with_a_one_line_warning(tmp_path, capsys):
    from conflictbench_lerobot.client import announce

    announce("eo1", str(tmp_path))
    said = capsys.readouterr().err.splitlines()
    assert said[0].endswith(f"plays a LeRobot eo1 policy ({tmp_path})")
    assert said[1].startswith("conflictbench: warning: untested policy type eo1 (tested: act, diffusion, multi_task")
    announce("act", str(tmp_path))
    assert len(capsys.readouterr().err.splitlines()) == 1
