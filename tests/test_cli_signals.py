"""A run ended by SIGTERM (a scheduler's time limit) stops as Ctrl-C does: one line, exit 130, work kept."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.sim


def test_sigterm_ends_a_run_cleanly_and_the_same_command_resumes(tmp_path):
    args = [sys.executable, "-m", "conflictbench.cli", "model=noop", "suite=physical", "level=L1",
            "run.init_states=2", "run.libero_suites=[libero_spatial]", "run.workers=1", "run.progress=false",
            "run.report=false", f"run.out={tmp_path / 'results'}"]  # fmt: skip
    run = subprocess.Popen(args, cwd=tmp_path, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    episodes = tmp_path / "results" / "episodes"
    deadline = time.monotonic() + 300
    while not (episodes.exists() and any(episodes.rglob("*.parquet"))) and time.monotonic() < deadline:
        time.sleep(0.1)
    run.send_signal(signal.SIGTERM)
    stderr = run.communicate(timeout=120)[1]
    assert run.returncode == 130, stderr[-3000:]
    assert stderr.rstrip().splitlines()[-1].startswith("conflictbench: interrupted; every finished episode is stored")
    assert "Traceback" not in stderr
    stored = len(list(episodes.rglob("*.parquet")))
    assert stored >= 1
    again = subprocess.run(args, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr[-3000:]
    assert "already stored" in again.stderr and f"{stored} already stored" in again.stderr
