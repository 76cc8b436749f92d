"""Starting the starVLA-format stand-in server for a test, and the statistics files the client reads."""

from __future__ import annotations

import json
from pathlib import Path

from conflictbench import ServerProcess
from conflictbench.testing import start_script_server

STANDIN = Path(__file__).resolve().parent / "starvla_standin_server.py"
#: A LIBERO-like action statistics entry: gripper excluded by the mask, as in OpenVLA-style statistics.
ACTION_STATS = {
    "min": [-0.9, -0.8, -0.7, -0.2, -0.3, -0.4, 0.0],
    "max": [0.9, 0.7, 0.9, 0.25, 0.35, 0.3, 1.0],
    "mask": [True, True, True, True, True, True, False],
}


def start_standin(tmp_path: Path, *options: str) -> tuple[ServerProcess, str]:
    """The stand-in on a free port, accepting connections; stop it with ``.stop()``."""
    return start_script_server(STANDIN, *options, scheme="ws", log_dir=tmp_path, name="vla-jepa-standin")


def write_run(folder: Path, window: int = 7, datasets: dict | None = None) -> Path:
    """A checkpoint run folder as upstream's client reads it: dataset_statistics.json and config.yaml."""
    folder.mkdir(parents=True, exist_ok=True)
    stats = datasets if datasets is not None else {"libero_goal_no_noops": {"action": ACTION_STATS}}
    (folder / "dataset_statistics.json").write_text(json.dumps(stats))
    (folder / "config.yaml").write_text(f"framework:\n  action_model:\n    future_action_window_size: {window}\n")
    return folder / "dataset_statistics.json"
