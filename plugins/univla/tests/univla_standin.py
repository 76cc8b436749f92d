"""Starting the UniVLA stand-in server (``univla_standin_server.py``) for a test."""

from __future__ import annotations

from pathlib import Path

from conflictbench import ServerProcess
from conflictbench.testing import start_script_server

STANDIN = Path(__file__).resolve().parent / "univla_standin_server.py"


def start_standin(tmp_path: Path, *options: str) -> tuple[ServerProcess, str]:
    """The stand-in on a free port, accepting connections; stop it with ``.stop()``."""
    return start_script_server(STANDIN, *options, scheme="http", log_dir=tmp_path, name="univla-standin")
