"""The tiny LeRobot checkpoints (lerobot_fixtures.py): laid out as LeRobot saves one, with LIBERO's inputs, and each
loads and plays LIBERO-shaped observations in the model environment as ``lerobot-eval`` plays them (LeRobot's
config, policy and processor loaders, its LIBERO environment processors, ``select_action`` over a whole chunk and
into the next). Marked ``model_env``: they need ``.venv/models/lerobot``."""

from __future__ import annotations

import json
import os

import pytest
from lerobot_fixtures import BUILDER, LEROBOT, TINY_TYPES, build_report, needs_model_env, parse_lines

#: What LeRobot's LIBERO datasets give a checkpoint (LeRobot's names: agentview, wrist; the 8-D state).
LIBERO_INPUTS = {
    "observation.images.image": {"type": "VISUAL", "shape": [3, 256, 256]},
    "observation.images.image2": {"type": "VISUAL", "shape": [3, 256, 256]},
    "observation.state": {"type": "STATE", "shape": [8]},
}
#: X-VLA keeps its 20-D ee6d action space; LeRobot's X-VLA environment post-processor makes LIBERO's 7 of it.
ACTION_DIMS = {"xvla": 20}
NORMALIZERS = ("normalizer_processor", "unnormalizer_processor")
#: Types that read the task text (ACT and Diffusion have no language input).
READS_TASK = {"smolvla", "pi05", "xvla", "multi_task_dit"}


@needs_model_env
@pytest.mark.parametrize("policy_type", TINY_TYPES)
def test_tiny_checkpoint_is_laid_out_as_lerobot_saves_one(policy_type, tiny_lerobot_checkpoints):
    folder = tiny_lerobot_checkpoints[policy_type]
    config = json.loads((folder / "config.json").read_text())
    assert config["type"] == policy_type
    assert config["input_features"] == LIBERO_INPUTS
    assert config["output_features"] == {"action": {"type": "ACTION", "shape": [ACTION_DIMS.get(policy_type, 7)]}}
    assert config["n_action_steps"] < config.get("chunk_size", config.get("horizon"))
    assert (folder / "model.safetensors").is_file()
    for name in ("policy_preprocessor", "policy_postprocessor"):
        steps = json.loads((folder / f"{name}.json").read_text())["steps"]
        assert all((folder / step["state_file"]).is_file() for step in steps if "state_file" in step)
        normalizing = [step for step in steps if step["registry_name"] in NORMALIZERS]
        assert len(normalizing) == 1 and "state_file" in normalizing[0], name  # statistics saved beside it


@pytest.fixture(scope="module")
def played(tiny_lerobot_checkpoints) -> dict[str, dict]:
    """Every checkpoint loaded and played by one model-environment process (``tiny_lerobot.py --check``), each from
    its own hub cache."""
    root = tiny_lerobot_checkpoints[TINY_TYPES[0]].parent
    argv = [str(BUILDER), "--type", *TINY_TYPES, "--out", str(root), "--no-build", "--check"]
    return parse_lines(LEROBOT.run(argv, timeout=600).stdout)


@needs_model_env
@pytest.mark.parametrize("policy_type", TINY_TYPES)
def test_tiny_checkpoint_plays_libero_observations_as_lerobot_eval(policy_type, played):
    """Loaded by LeRobot (from_pretrained and the saved processors; not through our server), on 360-px renders
    through LeRobot's LIBERO processors: every step of a chunk and the next gives one finite 7-D action, and the
    images and the state (and the task, where the type reads one) move it."""
    report = played[policy_type]
    assert report["render"] == 360
    assert all(len(action) == 7 for action in report["actions"])
    moved = report["moved_by"]
    assert moved["agentview_flipped"] > 1e-4 and moved["wrist_flipped"] > 1e-4, moved
    assert moved["state"] > 1e-5, moved
    assert (moved["task"] > 1e-4) == (policy_type in READS_TASK), moved


@needs_model_env
def test_tiny_lerobot_env_is_all_a_fresh_process_needs(tiny_lerobot_checkpoints, tiny_lerobot_env, played):
    """pi0.5, the type needing the most (its hub cache and the size patch), in a process given only
    ``tiny_lerobot_env``'s variables: the same first actions as in the process that played them all."""
    folder = tiny_lerobot_checkpoints["pi05"]
    argv = [str(BUILDER), "--type", "pi05", "--out", str(folder), "--no-build", "--check"]
    env = {**os.environ, **tiny_lerobot_env["pi05"]}
    report = parse_lines(LEROBOT.run(argv, timeout=300, env=env).stdout)["pi05"]
    assert report["hub_cache"] == str(folder / "hub")
    assert report["actions"] == played["pi05"]["actions"]


@needs_model_env
def test_tiny_checkpoints_are_the_same_bytes_when_built_again(tiny_lerobot_checkpoints, tmp_path):
    """Seeded throughout: a second build gives every file, stand-ins included, byte for byte (pinned actions
    recorded with one build hold for the next)."""
    argv = [str(BUILDER), "--type", *TINY_TYPES, "--out", str(tmp_path)]
    again = parse_lines(LEROBOT.run(argv, timeout=600).stdout)
    assert {t: again[t]["digest"] for t in TINY_TYPES} == {t: build_report[t]["digest"] for t in TINY_TYPES}
