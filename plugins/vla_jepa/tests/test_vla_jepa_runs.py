"""Real LIBERO episodes through ``conflictbench model=vla-jepa model.server=...`` against the starVLA stand-in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from jepa_standin import start_standin, write_run

from conflictbench.testing import (
    run_cli,
)
from conflictbench.testing.plugin_tests import played_one_case

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 16  # two chunks of eight (future_action_window_size 7)


def run(tmp_path: Path, url: str, *overrides: str):
    stats = write_run(tmp_path / "run", window=7)
    settings = ["model=vla-jepa", f"model.server={url}", "model.checkpoint=stand-in", f"model.stats={stats}"]
    return run_cli(tmp_path, *settings, f"model.max_steps={STEPS}", *overrides)


def test_episodes_play_whole_chunks_un_normalized_by_the_client(tmp_path):
    records = played_one_case(tmp_path, start_standin(tmp_path), lambda url: run(tmp_path, url), STEPS)
    for record in records:
        raw = record.raw_actions
        for start in (0, 8):  # the stand-in's rows grow linearly within a chunk; min/max keeps that (columns
            chunk = raw[start : start + 8][:, [0, 1, 4, 5]]  # that stay inside [-1, 1] before un-normalizing)
            np.testing.assert_allclose(chunk - chunk[0], np.outer(np.arange(8), chunk[1] - chunk[0]), atol=1e-6)
        assert not np.allclose(raw[8, [0, 1, 4, 5]], raw[0, [0, 1, 4, 5]] + 8 * (raw[1] - raw[0])[[0, 1, 4, 5]])
        assert raw[:, 6].tolist() == [1.0, -1.0] * 8  # stand-in gripper 0.2, 0.9 -> closed, open
    reference, conflict = records
    assert reference.raw_actions[0, 4] != conflict.raw_actions[0, 4]  # each episode's own text reached the server
