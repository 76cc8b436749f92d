"""Real LIBERO episodes through ``conflictbench model=pi05 model.server=...`` (openpi's own server, numpy stand-in)."""

from __future__ import annotations

import numpy as np
import pytest
from test_pi0_client import start_openpi_server

from conflictbench.store import EpisodeStore
from conflictbench.testing import run_cli

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 12


def test_episodes_play_against_openpis_server_executing_five_actions_of_each_chunk(tmp_path):
    server, url = start_openpi_server(tmp_path)
    try:
        settings = [f"model.server={url}", "model.checkpoint=stand-in", f"model.max_steps={STEPS}"]
        out = run_cli(tmp_path, "model=pi05", *settings)
    finally:
        server.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert "2 played, 0 already stored, 0 played by another job, 0 with errors" in out.stderr
    records = list(EpisodeStore(tmp_path / "results").records())
    assert len(records) == 2 and {r.case_id is None for r in records} == {True, False}
    for record in records:
        assert record.steps == STEPS and record.error is None
        raw = record.raw_actions
        # the stand-in's chunk row k is (k + 1) x its first row: 5 rows of each chunk, then a new query
        for step in range(STEPS):
            first = raw[5 * (step // 5)]
            np.testing.assert_allclose(raw[step], first * (step % 5 + 1), rtol=1e-5)
        assert not np.allclose(raw[5], raw[0] * 6)  # step 5 came from a new chunk, not row 5 of the old one
    reference, conflict = sorted(records, key=lambda r: r.case_id is not None)
    assert reference.raw_actions[0, 4] != conflict.raw_actions[0, 4]  # the prompt the server got differs
