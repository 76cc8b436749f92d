"""``conflictbench train-subject`` end to end on a tiny slice: real expert episodes in LIBERO, a LeRobot dataset
written and read back by LeRobot, a real PyTorch training run, and weights the NumPy network runs alike."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import conflictbench
from conflictbench.hosting import model_environment
from conflictbench.policies.subject.policy import SubjectConfig, SubjectPolicy

TRAINING_PYTHON = model_environment("subject") / "bin" / "python"
CHECK = Path(__file__).parent / "data" / "subject_check.py"
PACKAGE = Path(conflictbench.__file__).parent / "policies" / "subject"
COMMAND = Path(sys.executable).parent / "conflictbench"

needs_training_environment = pytest.mark.skipif(
    not TRAINING_PYTHON.exists() and not os.environ.get("CI"),  # CI builds it (scripts/setup.sh): there it must exist
    reason="the subject's training environment is not built (scripts/setup.sh)",
)


def train_subject(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([str(COMMAND), "train-subject", *args], cwd=cwd, env=env, capture_output=True, text=True)


@pytest.mark.sim
@pytest.mark.model_env
@needs_training_environment
def test_train_subject_records_writes_a_lerobot_dataset_and_trains_weights_the_policy_runs(tmp_path):
    out = tmp_path / "training"
    args = ["--out", str(out), "--libero-suites", "libero_goal", "--task-ids", "6,7", "--init-states", "10"]
    done = train_subject(*args, "--noise", "0", "--epochs", "2", "--threads", "1", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    demos = sorted((out / "demonstrations" / "episodes").glob("*.npz"))
    assert [p.name for p in demos] == ["libero_goal-06-010.npz", "libero_goal-07-010.npz"]
    lengths = [len(np.load(p)["label"]) for p in demos]
    report = json.loads((out / "training.json").read_text())
    assert report["demonstrations"] == 2 and report["training_s"] > 0

    checked = subprocess.run(
        [str(TRAINING_PYTHON), str(CHECK), str(PACKAGE), str(out / "dataset"), str(out / "subject.npz")],
        capture_output=True, text=True, env={**os.environ, "HF_HUB_OFFLINE": "1"},
    )  # fmt: skip
    assert checked.returncode == 0, checked.stderr[-3000:]
    seen = json.loads(checked.stdout.strip().splitlines()[-1])
    assert seen["episodes"] == 2 and seen["frames"] == sum(lengths)  # LeRobot reads back every frame
    assert seen["tasks"] == ["put the cream cheese in the bowl", "turn on the stove"]
    assert seen["first_task"] == "put the cream cheese in the bowl"
    assert seen["largest_difference"] < 1e-4  # the benchmark's NumPy network is the trained one

    policy = SubjectPolicy(SubjectConfig(weights=str(out / "subject.npz")))
    assert policy.network.config["seed"] == 0 and policy.network.config["epochs"] == 2

    recorded = {p: p.stat().st_mtime_ns for p in demos}
    again = train_subject(*args, "--noise", "0", "--epochs", "1", "--threads", "1", cwd=tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    assert {p: p.stat().st_mtime_ns for p in demos} == recorded  # a second run records nothing again


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--init-states", "ten"], "expected FIRST-LAST or a comma-separated list"),
        (["--libero-suites", "libero_100"], "invalid choice"),
        (["--init-states", "0-20"], "demonstration states must be in 5-49"),
        (["--task-ids", "3,12"], "task ids are 0-9"),
        (["--python", "/nowhere/python"], "no training environment at /nowhere/python"),
        (["--python", sys.executable], "cannot train the subject (ModuleNotFoundError"),
        (["--epochs", "0", "--python", sys.executable], "--epochs must be >= 1"),
    ],
)
def test_a_mistake_is_one_line(tmp_path, args, message):
    done = train_subject(*args, cwd=tmp_path)
    assert done.returncode == 2
    assert message in done.stderr and "Traceback" not in done.stderr
    assert done.stderr.count("\n") == 1
    assert not (tmp_path / "subject-training").exists()  # refused before anything was recorded
