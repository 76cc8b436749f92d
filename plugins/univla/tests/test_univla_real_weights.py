"""A real UniVLA checkpoint, where a machine has one: skipped with the reason unless the variables below say where.

- ``CONFLICTBENCH_UNIVLA_CHECKPOINT``: a UniVLA LIBERO checkpoint folder (the VLA and ``action_decoder.pt``);
- ``UNIVLA_CODE``: a checkout of OpenDriveLab/UniVLA (its model files);
- ``CONFLICTBENCH_UNIVLA_SUITE``: the LIBERO suite of the checkpoint (default ``libero_goal``).

Plays the suite's ten reference episodes at the first initial state on a GPU and expects most to succeed (UniVLA's
published LIBERO rates are above 90 %): a pipeline step done wrong shows as a collapse.
"""

from __future__ import annotations

import os

import pytest

from conflictbench.store import EpisodeStore
from conflictbench.testing import episode_counts, run_cli

pytestmark = [pytest.mark.sim, pytest.mark.slow]


def test_a_real_checkpoint_succeeds_on_most_reference_episodes(tmp_path):
    checkpoint, code = os.environ.get("CONFLICTBENCH_UNIVLA_CHECKPOINT"), os.environ.get("UNIVLA_CODE")
    if not checkpoint or not code:
        pytest.skip("CONFLICTBENCH_UNIVLA_CHECKPOINT and UNIVLA_CODE are not both set: no real UniVLA on this machine")
    suite = os.environ.get("CONFLICTBENCH_UNIVLA_SUITE", "libero_goal")
    out = run_cli(tmp_path, "model=univla", f"model.checkpoint={checkpoint}", "model.device=cuda", "suite=all",
                  "level=all", "run.cases_per_cell=0", f"run.libero_suites=[{suite}]", timeout=7200)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    played, _, errors = episode_counts(out.stderr)
    assert played == 10 and errors == 0
    successes = sum(record.success for record in EpisodeStore(tmp_path / "results").records())
    assert successes >= 5, f"{successes}/10 reference episodes succeeded"
