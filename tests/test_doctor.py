"""`conflictbench doctor`: the golden replays pass on the stack that made them, and fail with the right line when the
physics is perturbed or a golden frame is altered; its verdicts and the renderer-family classifier, each way."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conflictbench.core import UserError
from conflictbench.doctor import goldens as golden_files
from conflictbench.doctor.checks import Check, print_checks
from conflictbench.doctor.physics import PathComparison, physics_check, physics_passes
from conflictbench.doctor.rendering import FrameDifference, frame_difference, rendering_check, rendering_passes
from conflictbench.doctor.replaying import parse_perturbations

EXE = Path(sys.executable).parent / "conflictbench"


def doctor(*args: str, goldens: Path | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": "egl"}
    env.pop(golden_files.GOLDENS_VARIABLE, None)
    if goldens is not None:
        env[golden_files.GOLDENS_VARIABLE] = str(goldens)
    return subprocess.run([str(EXE), "doctor", *args], env=env, capture_output=True, text=True, timeout=900,
                          stdin=subprocess.DEVNULL)  # fmt: skip


def lines(done: subprocess.CompletedProcess) -> dict[str, str]:
    return {line.split()[0]: line for line in done.stdout.splitlines() if line.strip()}


def this_stacks_goldens(tmp_path: Path) -> Path:
    """A copy of the shipped goldens of this stack, to alter."""
    from conflictbench.sim.libero_env import simulator_versions

    key = golden_files.this_stack_key(simulator_versions())
    copy = tmp_path / key
    shutil.copytree(golden_files.GOLDENS_ROOT / key, copy)
    return copy


def alter_a_frame(folder: Path) -> None:
    from PIL import Image

    path = sorted((folder / golden_files.FRAMES).glob("*agentview*.png"))[0]
    frame = np.asarray(Image.open(path).convert("RGB")).copy()
    frame[100:104, 100:104] ^= 0xFF
    Image.fromarray(frame).save(path)


def one_golden(tmp_path: Path) -> Path:
    """This stack's goldens with their first episode only (libero_spatial's, the shortest): a real doctor run in a
    fraction of the whole's minute, for the default selection."""
    folder = this_stacks_goldens(tmp_path)
    meta = json.loads((folder / golden_files.META).read_text())
    meta["episodes"] = meta["episodes"][:1]
    (folder / golden_files.META).write_text(json.dumps(meta))
    return folder


# -- the doctor, run ---------------------------------------------------------------------------------------------
@pytest.mark.e2e  # costly (10-18 s): CI's marked lane plays it; the default selection stays under 10 min
@pytest.mark.sim
def test_doctor_replays_one_golden_with_and_without_cameras_and_passes(tmp_path):
    done = doctor("--goldens", str(one_golden(tmp_path)))
    said = lines(done)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "max path deviation 0 m" in said["physics"] and "success steps equal 2/2" in said["physics"]
    assert "agentview identical (3 frames)" in said["rendering"]
    assert "robot0_eye_in_hand identical (3 frames)" in said["rendering"]


@pytest.mark.sim
@pytest.mark.slow
def test_doctor_passes_on_the_stack_that_made_its_goldens():
    done = doctor()
    said = lines(done)
    assert done.returncode == 0, done.stdout + done.stderr
    assert set(said) == {"stack", "physics", "rendering"}
    assert all(line.split()[1] == "ok" for line in said.values())
    assert "max path deviation 0 m" in said["physics"] and "success steps equal 8/8" in said["physics"]
    assert "this stack's" in said["physics"]
    assert "agentview identical" in said["rendering"] and "robot0_eye_in_hand identical" in said["rendering"]
    assert "mujoco" in said["stack"] and "GL egl" in said["stack"] and "GPU" in said["stack"]


@pytest.mark.sim
@pytest.mark.slow
def test_perturbed_physics_fails_the_physics_line_with_its_deviation():
    done = doctor("--perturb", "iterations=5")
    said = lines(done)
    assert done.returncode == 1, done.stdout + done.stderr
    assert said["physics"].split()[1] == "FAIL"
    assert "max path deviation 0 m" not in said["physics"] and "physics perturbed: iterations=5" in said["physics"]


@pytest.mark.sim
@pytest.mark.slow
def test_an_altered_golden_frame_fails_the_rendering_line(tmp_path):
    goldens = this_stacks_goldens(tmp_path)
    alter_a_frame(goldens)
    done = doctor(goldens=goldens)
    said = lines(done)
    assert done.returncode == 1, done.stdout + done.stderr
    assert said["physics"].split()[1] == "ok"
    assert said["rendering"].split()[1] == "FAIL"
    assert "agentview differs in 1/12 frames" in said["rendering"]
    assert "robot0_eye_in_hand identical" in said["rendering"]


@pytest.mark.sim
@pytest.mark.slow
def test_frames_of_another_renderer_family_are_reported_without_failing(tmp_path):
    goldens = this_stacks_goldens(tmp_path)
    alter_a_frame(goldens)
    meta = json.loads((goldens / golden_files.META).read_text())
    meta["renderer_family"] = "nvidia"
    (goldens / golden_files.META).write_text(json.dumps(meta))
    done = doctor("--goldens", str(goldens))
    said = lines(done)
    assert done.returncode == 0, done.stdout + done.stderr
    assert said["rendering"].split()[1] == "ok" and "agentview differs in 1/12 frames" in said["rendering"]
    said_plainly = "the goldens' nvidia: frames from different renderers are not comparable pixel for pixel"
    assert said_plainly in said["rendering"]


@pytest.mark.e2e  # costly (10-18 s): CI's marked lane plays it; the default selection stays under 10 min
def test_a_mistake_in_doctors_arguments_is_one_line_and_exit_code_2(tmp_path):
    for args in (["--perturb", "gravity=0"], ["--goldens", str(tmp_path / "none")], ["stray"]):
        done = doctor(*args)
        assert done.returncode == 2, (args, done.stdout, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1 and not done.stdout


# -- its parts -----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("vendor", "renderer", "family"),
    [
        ("Mesa/X.org", "llvmpipe (LLVM 15.0.6, 256 bits)", "mesa-llvmpipe"),
        ("VMware, Inc.", "softpipe", "mesa-softpipe"),
        ("NVIDIA Corporation", "NVIDIA H200/PCIe/SSE2", "nvidia"),
        ("Mesa", "AMD Radeon Graphics (radeonsi, navi21, LLVM 15.0.7)", "mesa-hardware"),
        ("Intel", "Intel(R) UHD Graphics 630", "intel"),
        ("ATI Technologies Inc.", "AMD Radeon Pro 5500M", "amd"),
        ("", "", "other"),
    ],
)
def test_renderer_family(vendor, renderer, family):
    assert golden_files.renderer_family(vendor, renderer) == family


def test_physics_verdict_needs_equal_success_steps_and_a_path_within_tolerance():
    assert physics_passes(0.0, True, 1e-6)
    assert physics_passes(1e-6, True, 1e-6)
    assert not physics_passes(2e-6, True, 1e-6)
    assert not physics_passes(0.0, False, 1e-6)


def test_the_physics_line_names_the_episode_whose_success_step_moved():
    same = PathComparison("libero_goal-0-0", False, 0.0, 170, 170)
    moved = PathComparison("libero_goal-0-0", True, 0.0, None, 170)
    check = physics_check([same, moved], "goldens x", tolerance_m=1e-6)
    assert not check.passed and "success steps equal 1/2" in check.text
    assert "libero_goal-0-0 with cameras: never solved, golden solved at step 170" in check.text
    far = physics_check([PathComparison("e", False, 0.003, 5, 5)], "goldens x", tolerance_m=1e-6)
    assert not far.passed and "max path deviation 0.003 m" in far.text
    broken = physics_check([PathComparison("e", True, None, None, 5, "RuntimeError: no GL")], "x", tolerance_m=1e-6)
    assert not broken.passed and "e with cameras could not be replayed: RuntimeError: no GL" in broken.text


def test_rendering_verdict_fails_only_differing_frames_of_the_same_family():
    assert rendering_passes(True, True)
    assert rendering_passes(True, False)
    assert rendering_passes(False, False)
    assert not rendering_passes(False, True)


def test_frame_difference_counts_pixels_and_the_largest_channel_change():
    golden = np.zeros((4, 4, 3), np.uint8)
    frame = golden.copy()
    assert frame_difference("agentview", frame, golden) == FrameDifference("agentview", 0, 16, 0)
    frame[0, 0] = (0, 3, 0)
    frame[1, 2] = (250, 0, 0)
    assert frame_difference("agentview", frame, golden) == FrameDifference("agentview", 2, 16, 250)
    assert not frame_difference("agentview", np.zeros((2, 2, 3), np.uint8), golden).identical


def test_rendering_line_of_another_family_says_the_frames_are_not_comparable():
    differing = [FrameDifference("agentview", 10, 100, 7), FrameDifference("robot0_eye_in_hand", 0, 100, 0)]
    same = rendering_check(differing, "mesa-llvmpipe", "mesa-llvmpipe")
    assert not same.passed and "agentview differs in 1/1 frames (10.0% of their pixels, max |Δ| 7)" in same.text
    other = rendering_check(differing, "nvidia", "mesa-llvmpipe")
    assert other.passed and "not comparable pixel for pixel" in other.text


def test_the_nearest_goldens_are_chosen_by_mujocos_version_first():
    keys = ["py3.11-mujoco2.3.7", "py3.12-mujoco3.3.2"]
    assert golden_files.nearest(keys, "py3.12-mujoco3.3.3") == "py3.12-mujoco3.3.2"
    assert golden_files.nearest(keys, "py3.11-mujoco3.3.2") == "py3.12-mujoco3.3.2"
    assert golden_files.nearest(keys, "py3.12-mujoco2.3.7") == "py3.11-mujoco2.3.7"


def test_every_shipped_stack_has_its_goldens_and_they_read():
    for folder in sorted(p for p in golden_files.GOLDENS_ROOT.iterdir() if p.is_dir()):
        goldens = golden_files.read(folder)
        assert goldens.stack_key == folder.name and goldens.renderer_family == "mesa-llvmpipe"
        assert {e.suite for e in goldens.episodes} == {"libero_spatial", "libero_object", "libero_goal", "libero_10"}
        for e in goldens.episodes:
            assert goldens.eef_pos[e.name].shape == (len(goldens.actions[e.name]) + 1, 3)
            assert e.success_state == len(goldens.actions[e.name])
            for state in e.frame_states:
                assert goldens.frame(e.name, "agentview", state).shape == (goldens.image_size, goldens.image_size, 3)


def test_perturbations_parse_and_a_wrong_one_is_the_users_mistake():
    assert parse_perturbations(["iterations=5", "qpos_ulp=1"]) == (("iterations", 5.0), ("qpos_ulp", 1.0))
    with pytest.raises(UserError, match="the name is one of"):
        parse_perturbations(["gravity=0"])
    with pytest.raises(UserError, match="the value is a number"):
        parse_perturbations(["iterations=many"])


def test_print_checks_prints_one_line_each_and_says_whether_all_passed(capsys):
    assert not print_checks([Check("physics", True, "fine"), Check("rendering", False, "differs")], sys.stdout)
    assert capsys.readouterr().out == "physics    ok   fine\nrendering  FAIL differs\n"
    assert print_checks([], sys.stdout)


def test_a_mistake_in_the_models_overrides_is_said_before_any_replay(capsys):
    from conflictbench.cli import main

    started = time.perf_counter()
    assert main(["doctor", "model=pi05", "model.chekpoint=/x"]) == 2
    assert "no setting 'chekpoint'" in capsys.readouterr().err
    assert main(["doctor", "model.checkpoint=/x"]) == 2  # a setting without the model it belongs to
    assert "one model at a time" in capsys.readouterr().err
    assert time.perf_counter() - started < 30  # the replays take minutes: none ran
