"""The openvla model environment in tests: a tiny stand-in checkpoint built once per session (``tiny_openvla.py``),
and the environment its processes need (offline, the bfloat16 guard, one CPU thread, a modules cache of the
session's own for the checkpoint's code). Tests that use them skip where the environment is missing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
MODEL_PYTHON = Path(sys.prefix) / "models" / "openvla" / "bin" / "python"
REASON = f"no openvla model environment at {MODEL_PYTHON} (scripts/setup.sh --models openvla)"


def needs_model_env(test):
    """Marks a test that runs model-environment processes, and skips it where that environment is missing."""
    return pytest.mark.model_env(pytest.mark.skipif(not MODEL_PYTHON.exists(), reason=REASON)(test))


def model_env(checkpoint: Path) -> dict[str, str]:
    """os.environ plus what a process loading ``checkpoint`` needs."""
    return {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_MODULES_CACHE": str(checkpoint.parent / "hf_modules"),  # where trust_remote_code copies its code
        "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16",  # deploy.py's bfloat16, on a CPU
        "OMP_NUM_THREADS": "1",
        "TOKENIZERS_PARALLELISM": "false",
        "PYTHONPATH": str(TESTS),
    }


def run_in_model_env(argv: list[str], checkpoint: Path, timeout: float = 600, check: bool = True):
    done = subprocess.run([str(MODEL_PYTHON), *argv], env=model_env(checkpoint), capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip
    if check and done.returncode != 0:
        pytest.fail(f"{argv[0]} exited {done.returncode}:\n{done.stderr[-3000:]}", pytrace=False)
    return done


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory) -> Path:
    if not MODEL_PYTHON.exists():
        pytest.skip(REASON)
    folder = tmp_path_factory.mktemp("tiny-openvla") / "checkpoint"
    run_in_model_env([str(TESTS / "tiny_openvla.py"), str(folder)], folder)
    return folder


def start_server(checkpoint: Path, log_dir: Path, max_batch: int = 1):
    """``conflictbench-openvla serve`` for ``checkpoint`` on a free port, answering; ``(server, port)``."""
    from conflictbench import ServerProcess, free_port

    port = free_port()
    argv = [str(MODEL_PYTHON), "-m", "conflictbench_openvla", "serve", "--policy", "openvla", "--checkpoint",
            str(checkpoint), "--port", str(port), "--max-batch", str(max_batch)]  # fmt: skip
    server = ServerProcess(argv, name="openvla", health_url=f"http://127.0.0.1:{port}/healthz",
                           env=model_env(checkpoint), startup_timeout_s=300, log_dir=log_dir)  # fmt: skip
    return server.start(), port
