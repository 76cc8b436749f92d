"""Real LIBERO episodes through ``conflictbench model=openvla|openvla-oft model.server=...``, deploy.py stand-ins."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from deploy_standin import start_standin
from deploy_standin_model import STATS

from conflictbench.testing import (
    run_cli,
)
from conflictbench.testing.plugin_tests import played_one_case

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 16  # two OFT chunks of eight


def run(tmp_path: Path, name: str, url: str, *overrides: str):
    return run_cli(tmp_path, f"model={name}", f"model.server={url}", "model.checkpoint=stand-in",
                   f"model.max_steps={STEPS}", *overrides)  # fmt: skip


def played(tmp_path: Path, name: str, kind: str):
    return played_one_case(tmp_path, start_standin(tmp_path, kind), lambda url: run(tmp_path, name, url), STEPS)


def in_the_suites_range(raw: np.ndarray, key: str, epsilon: float) -> bool:
    action = STATS[key]["action"]
    low, high = np.array(action["q01"][:6]), np.array(action["q99"][:6]) + epsilon
    return bool(np.all(raw[:, :6] >= low - 1e-12) and np.all(raw[:, :6] <= high + 1e-12))


def test_openvla_episodes_query_every_step_with_the_episodes_suite_key(tmp_path):
    reference, conflict = played(tmp_path, "openvla", "openvla")
    for record in (reference, conflict):
        raw = record.raw_actions
        assert in_the_suites_range(raw, "libero_spatial", 0.0)  # the suite's statistics (the worker says which)
        assert len({tuple(row) for row in raw[:, :3]}) > STEPS // 2  # a new image, a new action, every step
        assert set(raw[:, 6]) <= {-1.0, 1.0}
    assert reference.raw_actions[0, 3] != conflict.raw_actions[0, 3]  # each episode's own text reached the server


def test_oft_episodes_execute_each_chunk_open_loop(tmp_path):
    reference, conflict = played(tmp_path, "openvla-oft", "oft")
    for record in (reference, conflict):
        raw = record.raw_actions
        assert in_the_suites_range(raw, "libero_goal", 1e-8)  # the key the server was started with
        for start in (0, 8):  # within a chunk the stand-in's rows grow linearly with the step (dims 0, 1)
            chunk = raw[start : start + 8, :2]
            np.testing.assert_allclose(chunk - chunk[0], np.outer(np.arange(8), chunk[1] - chunk[0]), atol=1e-9)
        assert not np.allclose(raw[8, :2], raw[0, :2] + 8 * (raw[1, :2] - raw[0, :2]))  # a new query at step 8
    assert reference.raw_actions[0, 3] != conflict.raw_actions[0, 3]
