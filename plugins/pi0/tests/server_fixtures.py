"""Policy servers as real processes on 127.0.0.1, for tests: ours or openpi's own, both in the model environment.

``start_server(kind, checkpoint, env, **options) -> (url, process)`` (a session fixture) starts
``python -m conflictbench_pi0 serve`` (``kind="ours"``) or ``tests/openpi_host.py`` (``kind="openpi"``:
openpi-server's ``WebsocketPolicyServer`` around the same backend) on a free port, waits for
``/healthz`` and stops every server it started when the session ends. A server that dies or does not
answer in time fails the test with the tail of its output.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Iterator, Mapping
from pathlib import Path

import pytest

from conflictbench import ServerProcess, free_port
from conflictbench_pi0.checkpoints import POLICY_TYPES

PLUGIN_ROOT = Path(__file__).resolve().parents[1]
OPENPI_HOST = Path(__file__).resolve().parent / "openpi_host.py"
MODEL_PYTHON = Path(sys.prefix) / "models" / "pi0" / "bin" / "python"
SERVER_KINDS = ("ours", "openpi")
#: Loading torch and a tiny model takes 10-20 s alone; a busy 2-core machine can take several times that.
STARTUP_TIMEOUT_S = 240.0

needs_model_env = pytest.mark.skipif(
    not MODEL_PYTHON.exists(), reason=f"no pi0 model environment at {MODEL_PYTHON} (scripts/setup.sh --models pi0)"
)


def policy_of(checkpoint: Path) -> str:
    """Our policy name (pi0, pi05, pi0-fast) for the LeRobot type in ``checkpoint``'s config."""
    kind = json.loads((Path(checkpoint) / "config.json").read_text())["type"]
    return next(name for name, lerobot_type in POLICY_TYPES.items() if lerobot_type == kind)


def server_argv(kind: str, checkpoint: Path, port: int, max_batch: int = 32, threads: int = 1) -> list[str]:
    if kind == "ours":
        return [
            str(MODEL_PYTHON), "-m", "conflictbench_pi0", "serve", "--policy", policy_of(checkpoint),
            "--checkpoint", str(checkpoint), "--host", "127.0.0.1", "--port", str(port),
            "--max-batch", str(max_batch), "--threads", str(threads),
        ]  # fmt: skip
    if kind == "openpi":
        return [
            str(MODEL_PYTHON), str(OPENPI_HOST), "--checkpoint", str(checkpoint), "--host", "127.0.0.1",
            "--port", str(port), "--threads", str(threads),
        ]  # fmt: skip
    raise ValueError(f"kind must be one of {SERVER_KINDS}, got {kind!r}")


def model_process_env(env: Mapping[str, str]) -> dict[str, str]:
    """This process's environment plus ``env`` (the tiny checkpoints' variables), the plugin importable, one
    CPU thread."""
    defaults = {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16", "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    merged = {**os.environ, **defaults, **env}
    paths = [str(PLUGIN_ROOT), *filter(None, [merged.get("PYTHONPATH", "")])]
    merged["PYTHONPATH"] = os.pathsep.join(paths)
    return merged


def launch_server(
    kind: str,
    checkpoint: Path,
    env: Mapping[str, str],
    *,
    max_batch: int = 32,
    threads: int = 1,
    startup_timeout_s: float = STARTUP_TIMEOUT_S,
) -> tuple[str, ServerProcess]:
    """A started, answering server of ``kind`` for ``checkpoint``; the caller stops it."""
    port = free_port()
    process = ServerProcess(
        server_argv(kind, checkpoint, port, max_batch, threads),
        name=f"pi0-{kind}",
        health_url=f"http://127.0.0.1:{port}/healthz",
        env=model_process_env(env),
        startup_timeout_s=startup_timeout_s,
    )
    try:
        process.start()
    except Exception as error:
        pytest.fail(f"the {kind} server for {checkpoint} did not start: {error}\n{process.log_tail(30)}", pytrace=False)
    return f"ws://127.0.0.1:{port}", process


@pytest.fixture(scope="session")
def start_server() -> Iterator:
    """``start_server(kind, checkpoint, env, **options) -> (url, process)``; all are stopped at the end."""
    started: list[ServerProcess] = []

    def start(kind: str, checkpoint: Path, env: Mapping[str, str], **options) -> tuple[str, ServerProcess]:
        url, process = launch_server(kind, checkpoint, env, **options)
        started.append(process)
        return url, process

    yield start
    for process in started:
        process.stop()
