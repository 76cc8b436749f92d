"""Tiny random-weight pi0 / pi0.5 / pi0-FAST checkpoints, built once per test session in the model environment.

``tiny_env`` (session) is the environment a model-environment process needs to load them: the test-only size
patches and this plugin on ``PYTHONPATH``, the offline hub cache the build fills as ``HF_HOME`` with
``HF_HUB_OFFLINE=1``, the bfloat16 guard and one CPU thread. ``tiny_checkpoints`` (session) maps our policy
names (pi0, pi05, pi0-fast) to the built folders. Both skip when the model environment is missing.
"""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path

import pytest

from conflictbench.testing import BASE_ENV, ModelEnvironment

PLUGIN_ROOT = Path(__file__).resolve().parents[1]
TINY_DIR = Path(__file__).resolve().parent / "tiny"
PATCHES = TINY_DIR / "patches"
PI0 = ModelEnvironment("pi0", Path(__file__).resolve().parent)
MODEL_PYTHON = PI0.python
TINY_POLICIES = ("pi0", "pi05", "pi0-fast")
#: A build imports torch and LeRobot (~10 s alone); three at once on a busy 2-core machine take longer.
BUILD_TIMEOUT_S = 600

model_env_missing, MODEL_ENV_REASON, needs_model_env = PI0.missing, PI0.reason, PI0.needs


#: Seconds the last session's tiny builds took (all three, in parallel), for reports.
build_seconds: dict[str, float] = {}


def tail(text: str, lines: int = 30) -> str:
    return "\n".join(text.splitlines()[-lines:])


def run_model_processes(commands: Mapping[str, list[str]], env: Mapping[str, str], timeout_s: float) -> None:
    """Run model-environment commands side by side; fail with a command's output tail if any fails."""
    full_env = {**os.environ, **env}
    started = {
        name: subprocess.Popen(
            [str(MODEL_PYTHON), *argv], env=full_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        for name, argv in commands.items()
    }
    failures = []
    for name, process in started.items():
        try:
            output, _ = process.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            output, _ = process.communicate()
            failures.append(f"{name}: no result after {timeout_s} s\n{tail(output)}")
            continue
        if process.returncode != 0:
            failures.append(f"{name}: exit {process.returncode}\n{tail(output)}")
    if failures:
        pytest.fail("\n\n".join(failures), pytrace=False)


@pytest.fixture(scope="session")
def tiny_env(tmp_path_factory) -> dict[str, str]:
    if model_env_missing:
        pytest.skip(MODEL_ENV_REASON)
    return {
        **BASE_ENV,  # offline, the bfloat16 guard, one CPU thread
        "PYTHONPATH": os.pathsep.join([str(PATCHES), str(PLUGIN_ROOT)]),
        "HF_HOME": str(tmp_path_factory.mktemp("tiny-hf-home")),
    }


@pytest.fixture(scope="session")
def tiny_checkpoints(tmp_path_factory, tiny_env) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("tiny-checkpoints")
    folders = {policy: root / policy for policy in TINY_POLICIES}
    commands = {
        policy: [str(TINY_DIR / "build.py"), "--policy", policy, "--out", str(folder), "--hf-home", tiny_env["HF_HOME"]]
        for policy, folder in folders.items()
    }
    start = time.perf_counter()
    run_model_processes(commands, tiny_env, BUILD_TIMEOUT_S)
    build_seconds["all"] = time.perf_counter() - start
    return folders
