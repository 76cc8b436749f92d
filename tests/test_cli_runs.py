"""Whole runs from the command line on real LIBERO episodes: plugins, sweeps, kills, concurrent jobs.

The policy is the pip-installed demo plugin (tests/plugins/conflictbench-demo), which declares
12 policy steps per episode so that these runs stay short.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from conflictbench.store import EpisodeStore

pytestmark = pytest.mark.sim

# A small suite file of shipped cases, so these runs plan few episodes: two base tasks of libero_goal at L1.
CASES = [
    ("libero_goal", 8, "instruction", "L1"),
    ("libero_goal", 1, "grounding", "L1"),
    ("libero_goal", 8, "spatial", "L1"),
    ("libero_goal", 1, "physical", "L1"),
    ("libero_goal", 3, "spatial", "L3"),
    ("libero_goal", 3, "physical", "L3"),
]
# 4 L1 cases on 2 tasks x 2 initial states + 2 tasks x 2 states of references = 12 episodes
SMALL_RUN_EPISODES = 12


@pytest.fixture
def suite_file(tmp_path) -> Path:
    from conflictbench.testing import shipped_cases_file

    return shipped_cases_file(tmp_path / "cases.jsonl", CASES)


def small_run(suite_file: Path) -> tuple[str, ...]:
    return ("model=demo-wave", "level=L1", "run.init_states=2", f"suite.file={suite_file}")


def counts(stderr: str) -> dict[str, int]:
    match = re.search(r"(\d+) played, (\d+) already stored, (\d+) played by another job, (\d+) with errors", stderr)
    assert match, stderr
    return dict(zip(("played", "stored", "elsewhere", "errors"), map(int, match.groups())))


def test_a_pip_installed_plugin_runs_end_to_end_and_its_metric_is_reported(cli, tmp_path):
    out = cli(
        "model=demo-wave",
        "model.amplitude=0.8",
        "suite=physical",
        "level=L1",
        "run.libero_suites=[libero_object]",
        "prompt=p1",
    )
    assert out.returncode == 0, out.stderr[-3000:]
    assert counts(out.stderr) == {"played": 2, "stored": 0, "elsewhere": 0, "errors": 0}
    assert "demo_path_ratio" in out.stdout and "physical" in out.stdout
    table = pd.read_csv(tmp_path / "results" / "report" / "table1_overall.csv")
    assert table.loc[0, "model"] == "demo-wave" and table.loc[0, "PCSR_n"] == 1
    assert 0 < table.loc[0, "demo_path_ratio"] < 10 and table.loc[0, "demo_path_ratio_n"] == 1

    records = EpisodeStore(tmp_path / "results").records()
    assert len(records) == 2 and {r.plugin for r in records} == {"conflictbench-demo"}
    assert {r.plugin_version for r in records} == {"0.3.1"}
    conflict = next(r for r in records if r.case_id)
    assert conflict.prompt_text == f"[p1] {conflict.instruction.upper()}"  # the plugin's prompt format
    np.testing.assert_array_equal(conflict.actions[:, 0], conflict.raw_actions[:, 0] * 0.5)  # its post-processor
    assert np.isclose(np.abs(conflict.raw_actions[:, 0]).max(), 0.8, atol=0.05)  # model.amplitude reached it


@pytest.mark.e2e
def test_a_second_models_run_keeps_the_first_in_the_stores_report(cli, tmp_path):
    """<run.out>/report/ describes the whole store (every model in it); the terminal shows this run's episodes."""
    quick = ("suite=physical", "level=L1", "run.libero_suites=[libero_object]", "run.max_steps=3")
    first = cli("model=noop", *quick)
    assert first.returncode == 0, first.stderr[-3000:]
    second = cli("model=demo-wave", *quick)
    assert second.returncode == 0, second.stderr[-3000:]
    table = pd.read_csv(tmp_path / "results" / "report" / "table1_overall.csv")
    assert sorted(table["model"]) == ["demo-wave", "noop"]
    assert "demo-wave" in second.stdout and "noop" not in second.stdout


@pytest.mark.e2e
def test_a_sweep_shares_one_store_and_never_replays_a_reference(cli, tmp_path, suite_file):
    out = cli("-m", "model=demo-wave", "suite=spatial,physical", "level=L3", f"suite.file={suite_file}")
    assert out.returncode == 0, out.stderr[-3000:]
    jobs = [
        counts(m.group(0))
        for m in re.finditer(r"\d+ played, \d+ already stored, \d+ played by another job, \d+ with errors", out.stderr)
    ]
    assert jobs == [
        {"played": 2, "stored": 0, "elsewhere": 0, "errors": 0},
        {"played": 1, "stored": 1, "elsewhere": 0, "errors": 0},
    ]
    records = EpisodeStore(tmp_path / "results").records()
    assert len(records) == 3 and sum(r.case_id is None for r in records) == 1
    assert {r.family for r in records if r.case_id} == {"spatial", "physical"}


def _start(cli_args, cwd: Path, demo_site: Path) -> subprocess.Popen:
    exe = Path(sys.executable).parent / "conflictbench"
    return subprocess.Popen(
        [str(exe), *cli_args],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(demo_site)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


@pytest.mark.e2e
def test_sigkill_loses_no_finished_episode_and_the_rerun_duplicates_none(cli, tmp_path, demo_plugin_site, suite_file):
    store = EpisodeStore(tmp_path / "results")
    proc = _start(small_run(suite_file), tmp_path, demo_plugin_site)
    deadline = time.time() + 300
    while len(store) < 3 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    assert proc.poll() is None, "the run ended before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)  # the main process and its simulator workers, mid-episode
    proc.wait()
    before = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in store.files()}
    assert 3 <= len(before) < SMALL_RUN_EPISODES
    assert len(store.records()) == len(before)  # every file on disk is a whole, readable episode

    out = cli(*small_run(suite_file))
    assert out.returncode == 0, out.stderr[-3000:]
    c = counts(out.stderr)
    assert c["stored"] == len(before) and c["played"] == SMALL_RUN_EPISODES - len(before)
    after = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in store.files()}
    assert len(after) == SMALL_RUN_EPISODES
    assert all(after[name] == before[name] for name in before)  # finished episodes were not replayed
    assert not list((tmp_path / "results" / "episodes").rglob("*.tmp"))
    assert not list((tmp_path / "results" / "claims").glob("*.claim"))


@pytest.mark.e2e
def test_two_jobs_on_one_store_play_every_episode_exactly_once(tmp_path, demo_plugin_site, suite_file):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    args = (*small_run(suite_file), f"run.out={tmp_path / 'shared'}")
    first = _start(args, tmp_path / "a", demo_plugin_site)
    time.sleep(1.0)
    second = _start(args, tmp_path / "b", demo_plugin_site)
    outs = [p.communicate(timeout=600) for p in (first, second)]
    assert [p.returncode for p in (first, second)] == [0, 0], [o[1][-2000:] for o in outs]
    played = [counts(err) for _, err in outs]
    assert played[0]["played"] + played[1]["played"] == SMALL_RUN_EPISODES
    assert all(c["played"] + c["stored"] + c["elsewhere"] == SMALL_RUN_EPISODES for c in played)
    assert len(EpisodeStore(tmp_path / "shared")) == SMALL_RUN_EPISODES
