"""Starting the deploy.py stand-in server (``deploy_standin_server.py``) for a test."""

from __future__ import annotations

from pathlib import Path

from conflictbench import ServerProcess
from conflictbench.testing import start_script_server

STANDIN = Path(__file__).resolve().parent / "deploy_standin_server.py"


def start_standin(tmp_path: Path, kind: str, *options: str) -> tuple[ServerProcess, str]:
    """The stand-in of ``kind`` (openvla, oft) on a free port, accepting connections; stop it with ``.stop()``."""
    return start_script_server(
        STANDIN, "--kind", kind, *options, scheme="http", log_dir=tmp_path, name=f"{kind}-standin"
    )
