"""Starting the NVIDIA-format stand-in server (``nvidia_standin_server.py``) for a test, and asking it things."""

from __future__ import annotations

import sys
from pathlib import Path

from conflictbench import ServerProcess, free_port
from conflictbench.hosting.zeromq import answers_ping

STANDIN = Path(__file__).resolve().parent / "nvidia_standin_server.py"


def start_standin(tmp_path: Path, *options: str, api_token: str | None = None) -> tuple[ServerProcess, str]:
    """The stand-in on a free port, answering pings; stop it with ``.stop()``."""
    port = free_port()
    url = f"tcp://127.0.0.1:{port}"
    argv = [sys.executable, str(STANDIN), str(port), *options]
    if api_token is not None:
        argv += ["--api-token", api_token]
    server = ServerProcess(
        argv, name="gr00t-standin", health_url=url, ready=lambda: answers_ping(url, api_token),
        startup_timeout_s=60, log_dir=tmp_path,
    )  # fmt: skip
    return server.start(), url
