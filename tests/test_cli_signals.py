"""A run ended by SIGTERM (a scheduler's time limit) or Ctrl-C: one line, exit 130, work kept, no tracebacks."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from testing_support import wait_until

pytestmark = pytest.mark.sim


@pytest.mark.e2e
def test_sigterm_ends_a_run_cleanly_and_the_same_command_resumes(tmp_path):
    args = [sys.executable, "-m", "conflictbench.cli", "model=noop", "suite=physical", "level=L1",
            "run.init_states=2", "run.libero_suites=[libero_spatial]", "run.workers=1", "run.progress=false",
            "run.report=false", f"run.out={tmp_path / 'results'}", "run.max_steps=40"]  # fmt: skip
    run = subprocess.Popen(args, cwd=tmp_path, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    episodes = tmp_path / "results" / "episodes"
    assert wait_until(lambda: episodes.exists() and any(episodes.rglob("*.parquet")), 300, every=0.1)
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


def _workers_of(parent: int) -> list[int]:
    """Simulator workers (multiprocessing spawn children) of ``parent``, from /proc."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            command, fields = (entry / "cmdline").read_bytes(), (entry / "stat").read_text().split()
        except (OSError, ValueError):
            continue
        if b"multiprocessing.spawn" in command and int(fields[3]) == parent:
            found.append(int(entry.name))
    return found


def _is_worker(pid: int) -> bool:
    """Whether ``pid`` is still a living simulator worker (not a zombie, not a new process given its number)."""
    try:
        command, state = (Path("/proc") / str(pid) / "cmdline").read_bytes(), (Path("/proc") / str(pid) / "stat")
        return b"multiprocessing.spawn" in command and state.read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _importing_the_simulator(pid: int) -> bool:
    """Whether worker ``pid`` has loaded MuJoCo's library: the simulator's imports are under way (seen about 2 s
    after the worker starts), the moment a terminal's Ctrl-C used to cost a traceback per worker."""
    try:
        return "mujoco" in (Path("/proc") / str(pid) / "maps").read_text()
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the workers through /proc")
def test_ctrl_c_while_workers_start_prints_only_the_interrupted_line(tmp_path):
    """A terminal's Ctrl-C reaches the whole process group; workers still importing the simulator used to print a
    KeyboardInterrupt traceback each. They are born ignoring SIGINT: the main process stops them."""
    args = [sys.executable, "-m", "conflictbench.cli", "model=random", "run.progress=false",
            f"run.out={tmp_path / 'results'}"]  # fmt: skip
    as_in_a_terminal = dict(start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    run = subprocess.Popen(args, cwd=tmp_path, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                           **as_in_a_terminal)  # fmt: skip
    assert wait_until(lambda: any(_importing_the_simulator(pid) for pid in _workers_of(run.pid)), 120)
    workers = _workers_of(run.pid)
    os.killpg(run.pid, signal.SIGINT)
    stderr = run.communicate(timeout=120)[1]
    assert run.returncode == 130, stderr[-3000:]
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr[-3000:]
    assert stderr.rstrip().splitlines()[-1].startswith("conflictbench: interrupted; every finished episode is stored")
    # the run has ended; its workers end with it (asked by pid: once their parent is gone, they would not be
    # its children any more)
    assert wait_until(lambda: not any(_is_worker(pid) for pid in workers), 10), "a simulator worker was left behind"
