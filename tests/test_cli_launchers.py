"""Sweeps through Hydra's maintained launchers (the `cluster` extra): jobs in other processes, one store."""

from __future__ import annotations

import os
import re

import pytest

from conflictbench.store import EpisodeStore
from conflictbench.testing import run_cli

pytestmark = [pytest.mark.sim, pytest.mark.cluster]  # sweeps through the submitit and Ray launchers
pytest.importorskip("hydra_plugins.hydra_submitit_launcher", reason="the cluster extra: pip install -e '.[cluster]'")


def job_logs(tmp_path) -> list[str]:
    return [p.read_text() for p in sorted((tmp_path / "results" / "hydra").rglob("*_log.err"))]


def test_a_submitit_sweep_runs_its_jobs_in_processes_of_their_own_into_one_store(tmp_path):
    """What `hydra/launcher=submitit_slurm` does on a cluster, on this machine: each job pickled, run elsewhere."""
    out = run_cli(tmp_path, "-m", "hydra/launcher=submitit_local", "model=noop,random", "run.report=true")
    assert out.returncode == 0, out.stderr[-3000:]
    stored = EpisodeStore(tmp_path / "results").records()
    assert sorted(r.policy for r in stored) == ["noop", "noop", "random", "random"]
    logs = job_logs(tmp_path)
    assert len(logs) == 2 and all("2 played, 0 already stored" in log for log in logs)  # the jobs' own output
    report = tmp_path / "results" / "report"
    combined = (report / "table1_overall.md").read_text()
    assert "noop" in combined and "random" in combined
    assert (report / "jobs" / "0-noop" / "table1_overall.md").is_file()


def test_two_jobs_wanting_the_same_episodes_play_each_once(tmp_path):
    """Two concurrent jobs of one policy (run.workers does not change an episode): the store's claims split them."""
    out = run_cli(tmp_path, "-m", "hydra/launcher=submitit_local", "model=noop", "run.workers=1,2")
    assert out.returncode == 0, out.stderr[-3000:]
    assert len(EpisodeStore(tmp_path / "results").records()) == 2
    closing = [
        re.search(r"(\d+) played, (\d+) already stored, (\d+) played by another job", log) for log in job_logs(tmp_path)
    ]
    assert all(closing) and sum(int(c[1]) for c in closing) == 2  # each episode played by exactly one job


def test_a_job_failing_in_its_own_process_is_one_line_naming_it_and_the_sweeps_exit_code(tmp_path):
    out = run_cli(tmp_path, "-m", "hydra/launcher=submitit_local", "model=noop", "run.init_states=1,52")
    assert out.returncode == 2, out.stderr[-3000:]  # the job's own exit code, a user's mistake
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert lines == ["conflictbench: error: sweep job 1: run.init_states=52, but LIBERO has 50 fixed initial states "
                     "per task"]  # fmt: skip
    assert len(EpisodeStore(tmp_path / "results").records()) == 2  # the other job's episodes


def test_a_ray_sweep_runs_each_job_as_a_ray_task_into_one_store_and_a_failed_job_is_named(tmp_path):
    """`hydra/launcher=ray` (ours: Hydra's cannot be installed beside the simulator) on a Ray started here. Four
    jobs: two play, two are refused (a user's mistake, in their own tasks): named, the sweep's exit code theirs."""
    pytest.importorskip("ray")
    out = run_cli(
        tmp_path, "-m", "hydra/launcher=ray", "hydra.launcher.cpus_per_job=1", "model=noop,random",
        "run.init_states=1,52", "run.report=true",
    )  # fmt: skip
    assert out.returncode == 2, out.stderr[-3000:]
    assert sorted(r.policy for r in EpisodeStore(tmp_path / "results").records()) == [
        "noop",
        "noop",
        "random",
        "random",
    ]
    jobs = re.findall(r"\(run_one pid=(\d+)\).*2 played, 0 already stored", out.stderr)  # Ray relays each job's lines
    assert len(set(jobs)) == 2  # two tasks, each in a process of its own
    for job in (1, 3):  # (noop, 52) and (random, 52)
        assert f"conflictbench: error: sweep job {job}: run.init_states=52, but LIBERO has 50" in out.stderr
    assert "Traceback" not in out.stderr
    assert (tmp_path / "results" / "report" / "jobs" / "2-random" / "table1_overall.md").is_file()
    assert "random" in (tmp_path / "results" / "report" / "table1_overall.md").read_text()  # the jobs together


def test_a_ray_job_whose_process_dies_is_named_and_recorded_and_the_others_are_kept(tmp_path, capfd):
    """A task that never returns (its worker crashed; a lost node is the same error family): one line, the
    sweep's failure record (the command's exit code), a result for Hydra instead of an exception."""
    ray = pytest.importorskip("ray")
    from omegaconf import OmegaConf

    from conflictbench.cli.sweep import collect_failures
    from hydra_plugins.conflictbench_ray_launcher.ray_launcher import RayLauncher

    def refuse():  # defined here: Ray ships it by value (this test module is not importable in its workers)
        from conflictbench.core import UserError

        raise UserError("the folder the sweep was launched from, /nowhere, is not on this node: share it")

    launcher = RayLauncher()
    launcher.config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path / "sweep")}}})
    ray.init(num_cpus=1, include_dashboard=False)
    try:
        crashed = ray.remote(max_retries=0)(lambda: os._exit(1)).remote()
        fine = ray.remote(lambda: "done").remote()
        result = launcher._outcome(ray, crashed, 1)
        assert ray.get(fine) == "done"
        mistaken = ray.remote(max_retries=0)(refuse).remote()  # as a job on a node without the launch folder
        refused = launcher._outcome(ray, mistaken, 2)
    finally:
        ray.shutdown()
    assert (result.return_value, refused.return_value) == (3, 2)  # lost: infrastructure; a mistake: the user's
    said = capfd.readouterr().err
    assert re.search(r"conflictbench: error: sweep job 1: its Ray task was lost \(\w*Crashed\w*", said)
    assert "conflictbench: error: sweep job 2: the folder the sweep was launched from, /nowhere, is not" in said
    failures = collect_failures(tmp_path / "sweep")
    assert [(f["job"], f["exit_code"]) for f in failures] == [(1, 3), (2, 2)]
