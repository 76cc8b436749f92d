"""Real LIBERO episodes through ``conflictbench model=gr00t model.server=...`` against the NVIDIA-format stand-in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gr00t_standin import start_standin

from conflictbench.testing import run_cli as run_one_case
from conflictbench.testing.plugin_tests import played_one_case

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 16  # two queries of eight actions


def run_cli(tmp_path: Path, url: str, *overrides: str):
    """``conflictbench model=gr00t`` against ``url`` on the one-case selection."""
    settings = ["model=gr00t", f"model.server={url}", "model.checkpoint=stand-in", f"model.max_steps={STEPS}"]
    return run_one_case(tmp_path, *settings, *overrides)


def test_episodes_play_eight_actions_of_each_chunk_from_the_first_step(tmp_path):
    records = played_one_case(tmp_path, start_standin(tmp_path), lambda url: run_cli(tmp_path, url), STEPS)
    for record in records:
        raw = record.raw_actions
        for step in range(STEPS):  # the stand-in's row k is (k + 1) x its first row: 8 rows, then a new query
            first = raw[8 * (step // 8)]
            np.testing.assert_allclose(raw[step, :6], first[:6] * (step % 8 + 1), rtol=1e-5)
        assert not np.allclose(raw[8, :6], raw[0, :6] * 9)  # step 8 came from a new chunk
        assert raw[:, 6].tolist() == ([1.0, -1.0, 0.0] * 3)[:8] * 2  # the gripper mapped from the dataset's [0, 1]
    reference, conflict = records
    assert reference.case_id is None and conflict.case_id is not None
    assert reference.raw_actions[0, 4] != conflict.raw_actions[0, 4]  # the server got each episode's own text
