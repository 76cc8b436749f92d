"""Real LIBERO episodes through ``conflictbench model=univla model.server=...`` against the stand-in server."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from univla_standin import start_standin
from univla_standin_model import STATISTICS

from conflictbench.testing import (
    run_cli,
)
from conflictbench.testing.plugin_tests import played_one_case

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 14  # past one window of 12


def run(tmp_path: Path, url: str, *overrides: str):
    settings = [f"model.server={url}", "model.checkpoint=stand-in", f"model.max_steps={STEPS}"]
    return run_cli(tmp_path, "model=univla", *settings, *overrides)


def test_episodes_query_every_step_with_their_history_and_the_suites_statistics(tmp_path):
    records = played_one_case(tmp_path, start_standin(tmp_path), lambda url: run(tmp_path, url), STEPS)
    action = STATISTICS["libero_spatial"]
    low, high = np.array(action["q01"][:6]), np.array(action["q99"][:6])
    for record in records:
        raw = record.raw_actions
        assert np.all(raw[:, :6] >= low - 1e-12) and np.all(raw[:, :6] <= high + 1e-12)
        assert set(raw[:, 6]) <= {-1.0, 1.0}
        assert len({tuple(row) for row in raw[:, :3]}) == STEPS  # a new ensembled action every step
    assert not np.array_equal(records[0].raw_actions[0], records[1].raw_actions[0])
