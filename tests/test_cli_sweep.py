"""A sweep's report: every job keeps its own tables, and the sweep ends with one report over all of them."""

from __future__ import annotations

import pytest

from conflictbench.testing import run_cli

pytestmark = pytest.mark.sim


def test_a_sweep_reports_its_jobs_apart_and_then_together(tmp_path):
    out = run_cli(tmp_path, "-m", "model=noop,random", "run.report=true")
    assert out.returncode == 0, out.stderr[-3000:]
    report = tmp_path / "results" / "report"
    combined = (report / "table1_overall.md").read_text()
    assert "noop" in combined and "random" in combined  # not the last job's alone
    noop, random = (
        (report / "jobs" / "0-noop" / "table1_overall.md").read_text(),
        (report / "jobs" / "1-random" / "table1_overall.md").read_text(),
    )
    assert "noop" in noop and "random" not in noop
    assert "random" in random and "noop" not in random
    assert "== the sweep's 2 jobs together (noop, random) ==" in out.stdout
    assert out.stdout.rstrip().endswith(f"tables and figures written to {report}/")


def test_variants_of_one_policy_are_stored_with_their_settings_and_reported_by_them(tmp_path):
    import json

    from conflictbench.store import EpisodeStore

    out = run_cli(tmp_path, "-m", "model=random", "model.seed=1,2", "run.report=true")
    assert out.returncode == 0, out.stderr[-3000:]
    settings = {r.policy_settings for r in EpisodeStore(tmp_path / "results").records()}
    assert {json.loads(s)["seed"] for s in settings} == {1, 2} and all("scale" in json.loads(s) for s in settings)
    combined = (tmp_path / "results" / "report" / "table1_overall.md").read_text()
    assert "random seed=1" in combined and "random seed=2" in combined
