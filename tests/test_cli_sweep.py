"""A sweep's report (every job its own tables, then one over all of them), and the plan's time estimate."""

from __future__ import annotations

import pytest

from conflictbench.testing import run_cli

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # sweeps of real episodes through the command


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
    assert out.stdout.count("Legend\n") == 1  # once, with the combined report
    assert out.stdout.index("== the sweep's 2 jobs") < out.stdout.index("Legend\n")


def test_variants_of_one_policy_are_stored_with_their_settings_and_reported_by_them(tmp_path):
    import json

    from conflictbench.store import EpisodeStore

    out = run_cli(tmp_path, "-m", "model=random", "model.seed=1,2", "run.report=true")
    assert out.returncode == 0, out.stderr[-3000:]
    settings = {r.policy_settings for r in EpisodeStore(tmp_path / "results").records()}
    assert {json.loads(s)["seed"] for s in settings} == {1, 2} and all("scale" in json.loads(s) for s in settings)
    combined = (tmp_path / "results" / "report" / "table1_overall.md").read_text()
    assert "random seed=1" in combined and "random seed=2" in combined


def test_the_plan_estimates_the_time_from_this_policys_earlier_episodes_or_says_it_cannot_yet(tmp_path):
    first = run_cli(tmp_path, "model=noop", "run.progress=true")
    assert first.returncode == 0, first.stderr[-3000:]
    assert "2 episode(s) to play, 0 already stored; the time left shows once the first episodes finish" in first.stderr
    again = run_cli(tmp_path, "model=noop", "run.progress=true", "run.libero_suites=[libero_goal]")
    assert again.returncode == 0, again.stderr[-3000:]
    line = next(line for line in again.stderr.splitlines() if "to play" in line)
    assert "0 already stored; about" in line and "per episode of its earlier episodes in this store" in line
