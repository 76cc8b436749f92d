"""Real LIBERO episodes through ``conflictbench model=gr00t model.server=...`` against the NVIDIA-format stand-in."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest
from gr00t_standin import start_standin

from conflictbench.core import INFRASTRUCTURE_ERROR_PREFIX
from conflictbench.store import EpisodeStore
from conflictbench.testing import episode_counts as counts
from conflictbench.testing import planned_conflict_instruction
from conflictbench.testing import run_cli as run_one_case

pytestmark = pytest.mark.sim
STEPS = 16  # two queries of eight actions


def run_cli(tmp_path: Path, url: str, *overrides: str):
    """``conflictbench model=gr00t`` against ``url`` on the one-case selection."""
    settings = ["model=gr00t", f"model.server={url}", "model.checkpoint=stand-in", f"model.max_steps={STEPS}"]
    return run_one_case(tmp_path, *settings, *overrides)


def test_episodes_play_eight_actions_of_each_chunk_from_the_first_step(tmp_path):
    server, url = start_standin(tmp_path)
    try:
        out = run_cli(tmp_path, url)
    finally:
        server.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert counts(out.stderr) == (2, 0, 0)
    records = list(EpisodeStore(tmp_path / "results").records())
    assert len(records) == 2 and {r.case_id is None for r in records} == {True, False}
    for record in records:
        assert record.steps == STEPS and record.error is None
        raw = record.raw_actions
        for step in range(STEPS):  # the stand-in's row k is (k + 1) x its first row: 8 rows, then a new query
            first = raw[8 * (step // 8)]
            np.testing.assert_allclose(raw[step, :6], first[:6] * (step % 8 + 1), rtol=1e-5)
        assert not np.allclose(raw[8, :6], raw[0, :6] * 9)  # step 8 came from a new chunk
        assert raw[:, 6].tolist() == ([1.0, -1.0, 0.0] * 3)[:8] * 2  # the gripper mapped from the dataset's [0, 1]
    reference, conflict = sorted(records, key=lambda r: r.case_id is not None)
    assert reference.raw_actions[0, 4] != conflict.raw_actions[0, 4]  # the server got each episode's own text


def test_a_malformed_reply_is_an_infrastructure_failure_left_out_and_played_again(tmp_path):
    failing, url = start_standin(tmp_path, "--fail-on", planned_conflict_instruction())
    try:
        out = run_cli(tmp_path, url)
    finally:
        failing.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert counts(out.stderr) == (2, 0, 1)
    store = EpisodeStore(tmp_path / "results")
    [failed] = [r for r in store.records() if r.error is not None]
    assert failed.case_id is not None and failed.error.startswith(INFRASTRUCTURE_ERROR_PREFIX)
    assert "action.gripper" in failed.error and store.replay_ids() == {failed.episode_id}

    healthy, url = start_standin(tmp_path)
    try:
        out = run_cli(tmp_path, url)
    finally:
        healthy.stop()
    assert counts(out.stderr) == (1, 1, 0), out.stderr[-3000:]
    assert store.replay_ids() == set() and all(r.error is None for r in store.records())


def test_a_server_killed_mid_run_stops_it_naming_the_url_and_the_same_command_resumes(tmp_path):
    server, url = start_standin(tmp_path)
    settings = ["run.init_states=2", "run.workers=1", "model.connect_retries=1", "model.backoff_s=0.2"]
    settings += ["model.connect_timeout_s=2"]
    episodes = tmp_path / "results" / "episodes"

    def kill_after_the_first_episode() -> None:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and not (episodes.exists() and any(episodes.rglob("*.parquet"))):
            time.sleep(0.1)
        server.stop(grace_s=0)

    killer = threading.Thread(target=kill_after_the_first_episode)
    killer.start()
    try:
        out = run_cli(tmp_path, url, *settings)
    finally:
        killer.join()
        server.stop()
    assert out.returncode == 3, out.stderr[-3000:]
    errors = [line for line in out.stderr.splitlines() if line.startswith("conflictbench: error:")]
    assert len(errors) == 1 and url in errors[0] and "Traceback" not in out.stderr, out.stderr[-3000:]
    store = EpisodeStore(tmp_path / "results")
    stored = {r.episode_id: r.raw_actions for r in store.records()}
    assert 1 <= len(stored) < 4 and all(r.error is None for r in store.records())

    server, again = start_standin(tmp_path)
    try:
        out = run_cli(tmp_path, again, *settings)  # another port: an address is no part of the identity
    finally:
        server.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert counts(out.stderr) == (4 - len(stored), len(stored), 0)
    after = {r.episode_id: r.raw_actions for r in EpisodeStore(tmp_path / "results").records()}
    assert len(after) == 4 and all(np.array_equal(after[e], stored[e]) for e in stored)
