"""Whole runs of a served policy on real LIBERO episodes: its server killed mid-run, its server failing an episode.

The policy is tests/plugins/conflictbench-served (the shared client, 10 policy steps per episode,
no cameras); its server is tests/policy_server.py on 127.0.0.1, a subprocess always stopped at teardown.
"""

from __future__ import annotations

import importlib.util
import io
import os
import re
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from policy_server import PolicyServer, served_action
from testing_support import conflict_spec, pip_install_into, reference_spec

import conflictbench
from conflictbench.core import INFRASTRUCTURE_ERROR_PREFIX, ConflictCase
from conflictbench.core.plugins import Plugins
from conflictbench.report import report_store
from conflictbench.report.summary import pair_up
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore
from conflictbench.tasks.libero.base_tasks import base_task
from conflictbench.testing import (
    check_failed_episode_is_replayed,
    check_killed_server_run_resumes,
    planned_conflict_instruction,
    run_cli,
)

pytestmark = pytest.mark.sim

SERVED_PLUGIN = Path(__file__).parent / "plugins" / "conflictbench-served"
# Two base tasks of libero_goal, two L1 cases each: 4 conflict + 2 reference episodes with one initial state.
CASES = [
    ("libero_goal", 8, "instruction", "L1"),
    ("libero_goal", 1, "grounding", "L1"),
    ("libero_goal", 8, "spatial", "L1"),
    ("libero_goal", 1, "physical", "L1"),
]
EPISODES, STEPS = 6, 10


@pytest.fixture
def servers():
    started: list[PolicyServer] = []

    def _start(*options: str, port: int = 0) -> PolicyServer:
        started.append(PolicyServer(*options, port=port))
        return started[-1]

    yield _start
    for server in started:
        server.stop()


@pytest.fixture(scope="module")
def served_plugin_site(tmp_path_factory) -> Path:
    """The served test plugin, pip-installed (a real distribution with a real entry point) into a directory."""
    target = tmp_path_factory.mktemp("served-plugin-site")
    pip_install_into(target, SERVED_PLUGIN)
    return target


def _cases_file(tmp_path: Path) -> Path:
    from conflictbench.testing import shipped_cases_file

    return shipped_cases_file(tmp_path / "cases.jsonl", CASES)


def _counts(stderr: str) -> dict[str, int]:
    match = re.search(r"(\d+) played, (\d+) already stored, (\d+) played by another job, (\d+) with errors", stderr)
    assert match, stderr[-3000:]
    return dict(zip(("played", "stored", "elsewhere", "errors"), map(int, match.groups())))


def _cli(args, cwd: Path, site: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(Path(sys.executable).parent / "conflictbench"), *args],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": str(site)},
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
    )


def test_no_server_stops_the_run_before_any_simulator_starts(tmp_path, served_plugin_site):
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{sock.getsockname()[1]}/act"
    out = _cli(
        [
            "model=served-test",
            f"model.server={url}",
            "level=L1",
            f"suite.file={_cases_file(tmp_path)}",
            "run.progress=false",
        ],
        tmp_path,
        served_plugin_site,
    )
    assert out.returncode == 3, out.stderr[-3000:]
    assert out.stderr.splitlines()[-1].startswith(f"conflictbench: error: the policy server at {url} cannot be reached")
    assert "Traceback" not in out.stderr and not (tmp_path / "results" / "episodes").exists()


@pytest.mark.e2e
def test_a_server_killed_mid_run_stops_it_naming_the_url_and_the_same_command_resumes(
    tmp_path, servers, served_plugin_site
):
    server = servers("--die-after", "25")  # two workers: each has finished about one episode by then
    args = [
        "model=served-test",
        f"model.server={server.url}",
        "level=L1",
        "run.init_states=1",
        f"suite.file={_cases_file(tmp_path)}",
        "run.workers=2",
        "run.progress=false",
        "run.report=false",
    ]

    def cli() -> subprocess.CompletedProcess:
        return _cli(args, tmp_path, served_plugin_site)

    out = cli()
    assert out.returncode == 3, out.stderr[-3000:]
    errors = [line for line in out.stderr.splitlines() if line.startswith("conflictbench: error:")]
    assert len(errors) == 1 and server.url in errors[0] and "connection refused" in errors[0], out.stderr[-3000:]
    assert "Traceback" not in out.stderr
    assert server.process.wait(timeout=5) != 0  # it really died

    store = EpisodeStore(tmp_path / "results")
    before = {p.name: p.read_bytes() for p in store.files()}
    assert 1 <= len(before) < EPISODES  # every episode finished before the crash is stored ...
    assert all(r.error is None and r.steps == STEPS for r in store.records())
    assert store.replay_ids() == set()  # ... and none of those cut off by it (they are simply not played yet)
    assert not list((tmp_path / "results" / "claims").glob("*.claim"))

    restarted = servers(port=server.port)  # the same URL again
    out = cli()
    assert out.returncode == 0, out.stderr[-3000:]
    assert _counts(out.stderr) == {"played": EPISODES - len(before), "stored": len(before), "elsewhere": 0, "errors": 0}
    assert restarted.stats()["requests"] == (EPISODES - len(before)) * STEPS  # only the missing episodes
    after = {p.name: p.read_bytes() for p in store.files()}
    assert len(after) == EPISODES and all(after[name] == before[name] for name in before)
    for record in store.records():  # the server's actions, executed
        np.testing.assert_allclose(record.raw_actions[:, 0], [served_action(t, [0.0] * 8)[0] for t in range(STEPS)])


def test_an_episode_the_server_fails_is_stored_left_out_and_played_again(play, servers, tmp_path):
    spec = importlib.util.spec_from_file_location(
        "conflictbench_served", SERVED_PLUGIN / "conflictbench_served" / "__init__.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[module])
    toaster = ConflictCase(
        "s-grnd-1",
        "libero_goal",
        1,
        base_task("libero_goal", 1).language,
        "put the bowl on the toaster",
        "grounding",
        "L1",
    )
    specs = [reference_spec("libero_goal", 1), conflict_spec(toaster)]

    failing = servers("--fail-instruction", "toaster")  # HTTP 500 for the conflict episode's requests
    result, store = play("served-test", specs, settings={"server": failing.url}, workers=2, plugin_set=plugins)
    assert (result.played, result.errors) == (2, 1)
    [failed] = [r for r in store.records() if r.case_id]
    assert failed.error.startswith(INFRASTRUCTURE_ERROR_PREFIX) and "HTTP 500" in failed.error
    assert failed.infrastructure_failed and store.replay_ids() == {failed.episode_id}
    pairs, counts = pair_up(store.records())
    assert pairs == [] and [r.episode_id for r in counts.unserved] == [failed.episode_id]
    text = io.StringIO()
    report_store(store, plugins, stream=text, figures=False)  # what `conflictbench report DIR` prints
    assert "1 episode(s) left out, with their pairs, and played again by the next run: 1 server" in text.getvalue()

    # Failing the same way again: the next runs leave it waiting, and say so, until told to retry.
    result, store = play("served-test", specs, settings={"server": failing.url}, workers=2, plugin_set=plugins)
    assert (result.already_stored, result.played, result.errors) == (1, 1, 1)
    assert store.repeated_failure_ids() == {failed.episode_id}
    healthy = servers()
    result, store = play("served-test", specs, settings={"server": healthy.url}, workers=2, plugin_set=plugins)
    assert (result.already_stored, result.played, result.failed_twice) == (1, 0, 1)
    assert healthy.stats()["requests"] == 0
    spec = plugins.policy("served-test")
    config = spec.make_config({"server": healthy.url})
    result = Runner(plugins, spec, config, store=store, workers=2, progress=False, retry=True).run(specs)
    assert (result.already_stored, result.played, result.errors) == (1, 1, 0)  # only the failed one, again
    assert healthy.stats()["requests"] == STEPS
    assert store.replay_ids() == set() and [r.error for r in store.records()] == [None, None]
    pairs, counts = pair_up(store.records())
    assert len(pairs) == 1 and counts.unserved == []


@pytest.mark.e2e
def test_the_end_to_end_checks_a_plugin_runs_on_its_server_hold_for_a_served_plugin(tmp_path, served_plugin_site):
    """conflictbench.testing's two checks, called as a model plugin calls them, with the served test plugin and its
    server: an episode the server fails is stored, left out and played again; a server killed mid-run stops the run
    in one line and the same command resumes it. (The model plugins' own tests check how each transport maps a
    server's error and a lost server, at unit level: this is the one end-to-end run of both.)"""
    path = os.pathsep.join(filter(None, [str(served_plugin_site), os.environ.get("PYTHONPATH")]))
    env = {**os.environ, "PYTHONPATH": path}

    def start(*options: str) -> tuple[PolicyServer, str]:
        server = PolicyServer(*options)
        return server, server.url

    def run(url: str, *more: str) -> subprocess.CompletedProcess:
        return run_cli(tmp_path, "model=served-test", f"model.server={url}", *more, env=env)

    failing = planned_conflict_instruction()
    check_failed_episode_is_replayed(
        tmp_path, lambda: start("--fail-instruction", failing), start, run, error_text="HTTP 500"
    )
    shutil.rmtree(tmp_path / "results")
    check_killed_server_run_resumes(tmp_path, start, run)


def test_every_worker_keeps_its_request_in_flight_while_the_others_wait_for_theirs(play, servers):
    """Two workers, a server that answers a request only once a second one waits beside it: the runner
    sends each query as it comes (it does not wait for the other worker's answer), so the requests meet.
    A runner that asked one at a time would leave every request alone until the server's timeout."""
    spec = importlib.util.spec_from_file_location(
        "conflictbench_served", SERVED_PLUGIN / "conflictbench_served" / "__init__.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[module])
    specs = [reference_spec("libero_goal", 1, 0), reference_spec("libero_spatial", 0, 0)]
    meeting = servers("--meet", "2", "--meet-timeout-s", "20")  # a scene compiled by one worker, loaded by the other
    result, store = play("served-test", specs, settings={"server": meeting.url}, workers=2, plugin_set=plugins)
    assert (result.played, result.errors) == (2, 0)
    stats = meeting.stats()
    assert stats["requests"] == 2 * STEPS and stats["max_in_flight"] == 2
    # One worker may reach its first query while the other still builds its scene (that one waits
    # alone); from then on the two workers' queries meet step by step.
    assert stats["alone"] <= 2 and stats["met"] >= 2 * STEPS - 2, stats
