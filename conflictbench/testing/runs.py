"""Real runs of the ``conflictbench`` command on a small selection (:data:`ONE_CASE`), and stand-in servers.

Needs the simulator (the ``sim`` extra) but for :func:`start_script_server`; mark such tests ``sim`` and ``e2e``.
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Protocol

#: One physical L1 case of libero_spatial and its reference, first initial state, no progress bar or report.
ONE_CASE = ("suite=physical", "level=L1", "run.cases_per_cell=1", "run.libero_suites=[libero_spatial]")
#: :func:`run_cli`'s step cap (``run.max_steps``): what its tests check (stores, identities, launchers, servers) is
#: the same after 40 steps as after LIBERO's 220, in a fifth of the simulator's time.
QUICK_STEPS = 40


def run_cli(
    tmp_path: Path,
    *overrides: str,
    out: str = "results",
    env: Mapping[str, str] | None = None,
    timeout: float = 900,
    max_steps: int | None = QUICK_STEPS,
) -> subprocess.CompletedProcess:
    """``conflictbench`` on :data:`ONE_CASE` with ``overrides``, its store in ``tmp_path / out``, each episode capped
    at ``max_steps`` (``None``: the policy's whole budget)."""
    cap = [] if max_steps is None else [f"run.max_steps={max_steps}"]
    args = [*ONE_CASE, *cap, "run.progress=false", "run.report=false", f"run.out={tmp_path / out}", *overrides]
    return subprocess.run(
        [sys.executable, "-m", "conflictbench.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
        cwd=tmp_path,
        env=None if env is None else dict(env),
    )


def episode_counts(stderr: str) -> tuple[int, int, int]:
    """(played, already stored, with errors) from a run's closing line."""
    found = re.search(r"(\d+) played, (\d+) already stored, \d+ played by another job, (\d+) with errors", stderr)
    if found is None:
        raise AssertionError(f"no closing line in the run's output:\n{stderr[-3000:]}")
    return int(found[1]), int(found[2]), int(found[3])


def planned_conflict_instruction() -> str:
    """The conflict instruction :data:`ONE_CASE` plays (a server can be told to fail on exactly that episode)."""
    from ..sim.plan import build_plan
    from ..tasks.libero.base_tasks import all_base_tasks
    from ..tasks.suite.file import load_suite

    tasks = {t.key: t.language for t in all_base_tasks(("libero_spatial",))}
    plan = build_plan(
        load_suite(None).cases, base_instructions=tasks, families=["physical"], levels=["L1"], prompts=["p0"],
        init_states=[0], cases_per_cell=1, sample_seed=0, libero_suites=["libero_spatial"],
    )  # fmt: skip
    [conflict] = [spec for spec in plan if spec.case is not None]
    return conflict.case.instruction


class _Stoppable(Protocol):
    def stop(self, grace_s: float = ...) -> None: ...


#: ``start() -> (server, url)``: a policy server started for a test (anything with ``stop(grace_s)``).
StartServer = Callable[[], tuple[_Stoppable, str]]
#: ``run(url, *overrides) -> CompletedProcess``: the plugin's one-case run against the server at ``url``.
RunAgainst = Callable[..., subprocess.CompletedProcess]


def check_failed_episode_is_replayed(
    tmp_path: Path, start_failing: StartServer, start_healthy: StartServer, run: RunAgainst, error_text: str
) -> None:
    """A server failing on the one-case run's conflict episode (``start_failing``, e.g. told to fail on
    :func:`planned_conflict_instruction`): that episode is stored as an infrastructure failure naming
    ``error_text``, left out and listed for replay; the same command against ``start_healthy`` plays it again."""
    from ..core import INFRASTRUCTURE_ERROR_PREFIX
    from ..store import EpisodeStore

    server, url = start_failing()
    try:
        out = run(url)
    finally:
        server.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert episode_counts(out.stderr) == (2, 0, 1)
    store = EpisodeStore(tmp_path / "results")
    [failed] = [r for r in store.records() if r.error is not None]
    assert failed.case_id is not None and failed.error.startswith(INFRASTRUCTURE_ERROR_PREFIX)
    assert error_text in failed.error and store.replay_ids() == {failed.episode_id}, failed.error

    server, url = start_healthy()
    try:
        out = run(url)
    finally:
        server.stop()
    assert episode_counts(out.stderr) == (1, 1, 0), out.stderr[-3000:]
    assert store.replay_ids() == set() and all(r.error is None for r in store.records())


def check_killed_server_run_resumes(tmp_path: Path, start: StartServer, run: RunAgainst) -> None:
    """A server killed once the first of four episodes is stored (one worker) stops the run with one line naming
    its URL (exit 3, no traceback), nothing half-played is stored, and the same command against a new server
    plays exactly the rest, leaving the stored episodes as they were."""
    import numpy as np

    from ..store import EpisodeStore

    settings = ["run.init_states=2", "run.workers=1", "model.connect_retries=1", "model.backoff_s=0.2"]
    episodes = tmp_path / "results" / "episodes"
    server, url = start()

    def kill_after_the_first_episode() -> None:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and not (episodes.exists() and any(episodes.rglob("*.parquet"))):
            time.sleep(0.1)
        server.stop(grace_s=0)

    killer = threading.Thread(target=kill_after_the_first_episode)
    killer.start()
    try:
        out = run(url, *settings)
    finally:
        killer.join()
        server.stop()
    assert out.returncode == 3, out.stderr[-3000:]
    errors = [line for line in out.stderr.splitlines() if line.startswith("conflictbench: error:")]
    assert len(errors) == 1 and url in errors[0] and "Traceback" not in out.stderr, out.stderr[-3000:]
    stored = {r.episode_id: r.raw_actions for r in EpisodeStore(tmp_path / "results").records()}
    assert 1 <= len(stored) < 4

    server, url = start()
    try:
        out = run(url, *settings)
    finally:
        server.stop()
    assert out.returncode == 0, out.stderr[-3000:]
    assert episode_counts(out.stderr) == (4 - len(stored), len(stored), 0)
    after = {r.episode_id: r.raw_actions for r in EpisodeStore(tmp_path / "results").records()}
    assert len(after) == 4 and all(np.array_equal(after[e], stored[e]) for e in stored)


def start_script_server(script: Path, *args: str, scheme: str, log_dir: Path, name: str | None = None):
    """``python script PORT *args`` (a test's stand-in of an upstream server) on a free port, started once it
    accepts connections; ``(server, "scheme://127.0.0.1:PORT")``. Stop it with ``server.stop()``."""
    import socket

    from ..hosting import ServerProcess, free_port

    port = free_port()

    def accepting() -> bool:
        with socket.socket() as sock:
            sock.settimeout(1.0)
            return sock.connect_ex(("127.0.0.1", port)) == 0

    url = f"{scheme}://127.0.0.1:{port}"
    server = ServerProcess([sys.executable, str(script), str(port), *args], name=name or Path(script).stem,
                           health_url=url, ready=accepting, startup_timeout_s=60, log_dir=log_dir)  # fmt: skip
    return server.start(), url


def shipped_cases_file(path: Path, picks: Iterable[tuple[str, int, str, str]]) -> Path:
    """A small suite file for a test run: for each ``(libero suite, task id, family, level)`` the first such
    case of the shipped suite (valid by construction: a run refuses a file whose cases break the rules)."""
    from ..tasks.suite.file import case_line, load_suite

    cases = load_suite().cases
    lines = []
    for suite, task_id, family, level in picks:
        found = next(c for c in cases if (c.suite, c.task_id, c.family, c.level) == (suite, task_id, family, level))
        lines.append(case_line(found) + "\n")
    path.write_text("".join(lines))
    return path
