"""Starting the UniVLA stand-in server (``univla_standin_server.py``) for a test."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

from conflictbench import ServerProcess, free_port

STANDIN = Path(__file__).resolve().parent / "univla_standin_server.py"


def accepting(port: int) -> bool:
    with socket.socket() as sock:
        sock.settimeout(1.0)
        return sock.connect_ex(("127.0.0.1", port)) == 0


def start_standin(tmp_path: Path, *options: str) -> tuple[ServerProcess, str]:
    """The stand-in on a free port, accepting connections; stop it with ``.stop()``."""
    port = free_port()
    server = ServerProcess(
        [sys.executable, str(STANDIN), str(port), *options], name="univla-standin",
        health_url=f"http://127.0.0.1:{port}/act", ready=lambda: accepting(port), startup_timeout_s=60,
        log_dir=tmp_path,
    )  # fmt: skip
    return server.start(), f"http://127.0.0.1:{port}"
