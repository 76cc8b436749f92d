"""The univla model environment in tests: a tiny checkpoint for the stand-in UniVLA checkout, built once per session
(``tiny_univla.py``), and the environment its processes need (``UNIVLA_CODE`` naming the stand-in checkout, the
bfloat16 guard, one CPU thread). Tests that use them skip where the environment is missing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
CODE = TESTS / "standin_univla_code"
MODEL_PYTHON = Path(sys.prefix) / "models" / "univla" / "bin" / "python"
REASON = f"no univla model environment at {MODEL_PYTHON} (scripts/setup.sh --models univla)"


def needs_model_env(test):
    """Marks a test that runs model-environment processes, and skips it where that environment is missing."""
    return pytest.mark.model_env(pytest.mark.skipif(not MODEL_PYTHON.exists(), reason=REASON)(test))


def model_env() -> dict[str, str]:
    """os.environ plus what a process loading the tiny checkpoint needs."""
    return {
        **os.environ,
        "UNIVLA_CODE": str(CODE),
        "HF_HUB_OFFLINE": "1",
        "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16",  # UniVLA's bfloat16, on a CPU
        "OMP_NUM_THREADS": "1",
        "PYTHONPATH": str(TESTS),
    }


def run_in_model_env(argv: list[str], timeout: float = 600, check: bool = True, env: dict | None = None):
    done = subprocess.run([str(MODEL_PYTHON), *argv], env=env or model_env(), capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip
    if check and done.returncode != 0:
        pytest.fail(f"{argv[0]} exited {done.returncode}:\n{done.stderr[-3000:]}", pytrace=False)
    return done


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory) -> Path:
    if not MODEL_PYTHON.exists():
        pytest.skip(REASON)
    folder = tmp_path_factory.mktemp("tiny-univla") / "checkpoint"
    run_in_model_env([str(TESTS / "tiny_univla.py"), str(folder)])
    return folder
