"""Real LIBERO episodes through ``conflictbench model=vla-jepa model.server=...`` against the starVLA stand-in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from jepa_standin import start_standin, write_run

from conflictbench.store import EpisodeStore
from conflictbench.testing import (
    episode_counts,
    run_cli,
)

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 16  # two chunks of eight (future_action_window_size 7)


def run(tmp_path: Path, url: str, *overrides: str):
    stats = write_run(tmp_path / "run", window=7)
    settings = ["model=vla-jepa", f"model.server={url}", "model.checkpoint=stand-in", f"model.stats={stats}"]
    return run_cli(tmp_path, *settings, f"model.max_steps={STEPS}", *overrides)


def test_episodes_play_whole_chunks_un_normalized_by_the_client(tmp_path):
    server, url = start_standin(tmp_path)
    try:
        out = run(tmp_path, url)
    finally:
        server.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert episode_counts(out.stderr) == (2, 0, 0)
    records = list(EpisodeStore(tmp_path / "results").records())
    assert len(records) == 2
    for record in records:
        assert record.steps == STEPS and record.error is None
        raw = record.raw_actions
        for start in (0, 8):  # the stand-in's rows grow linearly within a chunk; min/max keeps that (columns
            chunk = raw[start : start + 8][:, [0, 1, 4, 5]]  # that stay inside [-1, 1] before un-normalizing)
            np.testing.assert_allclose(chunk - chunk[0], np.outer(np.arange(8), chunk[1] - chunk[0]), atol=1e-6)
        assert not np.allclose(raw[8, [0, 1, 4, 5]], raw[0, [0, 1, 4, 5]] + 8 * (raw[1] - raw[0])[[0, 1, 4, 5]])
        assert raw[:, 6].tolist() == [1.0, -1.0] * 8  # stand-in gripper 0.2, 0.9 -> closed, open
    reference, conflict = sorted(records, key=lambda r: r.case_id is not None)
    assert reference.raw_actions[0, 4] != conflict.raw_actions[0, 4]  # each episode's own text reached the server
