"""The GR00T model environment in tests: a tiny random-weight checkpoint built once per session (its base model
and VLM processor in a Hugging Face cache of its own), and the environment its processes need (that cache,
offline, the bfloat16 guard, one CPU thread). Tests that use them skip where the environment is missing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
MODEL_PYTHON = Path(sys.prefix) / "models" / "gr00t" / "bin" / "python"
REASON = f"no gr00t model environment at {MODEL_PYTHON} (scripts/setup.sh --models gr00t)"


def needs_model_env(test):
    """Marks a test that runs model-environment processes, and skips it where that environment is missing."""
    return pytest.mark.model_env(pytest.mark.skipif(not MODEL_PYTHON.exists(), reason=REASON)(test))


def model_env(checkpoint: Path) -> dict[str, str]:
    """os.environ plus what a process loading ``checkpoint`` (built by tiny_groot.py) needs."""
    return {
        **os.environ,
        "HF_HOME": str(checkpoint / "hf_home"),  # its base model and processor, cached under their hub names
        "HF_HUB_OFFLINE": "1",
        "TRANSFORMERS_OFFLINE": "1",
        "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16",  # GR00T runs under bfloat16 autocast
        "OMP_NUM_THREADS": "1",
        "TOKENIZERS_PARALLELISM": "false",
        "PYTHONPATH": str(TESTS),
    }


def run_in_model_env(argv: list[str], checkpoint: Path, timeout: float = 600) -> str:
    done = subprocess.run([str(MODEL_PYTHON), *argv], env=model_env(checkpoint), capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip
    if done.returncode != 0:
        pytest.fail(f"{argv[0]} exited {done.returncode}:\n{done.stderr[-3000:]}", pytrace=False)
    return done.stdout


@pytest.fixture(scope="session")
def tiny_groot_checkpoint(tmp_path_factory) -> Path:
    if not MODEL_PYTHON.exists():
        pytest.skip(REASON)
    folder = tmp_path_factory.mktemp("tiny-gr00t") / "checkpoint"
    run_in_model_env([str(TESTS / "tiny_groot.py"), str(folder)], folder)
    return folder
