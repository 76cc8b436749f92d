"""Helpers for a model plugin's own tests: real runs of the ``conflictbench`` command on a small selection.

The selection (:data:`ONE_CASE`) is one physical-feasibility L1 case of libero_spatial and its reference
episode, at the first initial state: two real LIBERO episodes, about half a minute each on a CPU. ::

    from conflictbench.testing import episode_counts, planned_conflict_instruction, run_cli

    out = run_cli(tmp_path, "model=mymodel", "model.server=...", "model.max_steps=16")
    assert out.returncode == 0 and episode_counts(out.stderr) == (2, 0, 0)

and two checks every served model's plugin can run against its own servers:
:func:`check_failed_episode_is_replayed` and :func:`check_killed_server_run_resumes`.

Needs the simulator (the ``sim`` extra); mark such tests ``@pytest.mark.sim``.
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


def run_cli(
    tmp_path: Path,
    *overrides: str,
    out: str = "results",
    env: Mapping[str, str] | None = None,
    timeout: float = 900,
) -> subprocess.CompletedProcess:
    """``conflictbench`` on :data:`ONE_CASE` with ``overrides``, its store in ``tmp_path / out``."""
    args = [*ONE_CASE, "run.progress=false", "run.report=false", f"run.out={tmp_path / out}", *overrides]
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
    from .sim.plan import build_plan
    from .tasks.libero.base_tasks import all_base_tasks
    from .tasks.suite.file import load_suite

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
    from .core import INFRASTRUCTURE_ERROR_PREFIX
    from .store import EpisodeStore

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

    from .store import EpisodeStore

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


def camera_observation(
    step: int = 0, instruction: str = "put the bowl on the plate", stream: int = 0, suite: str = "libero_goal"
):
    """An observation as a worker sends it to a policy that looks: two random 256-px renders (fixed by ``step``),
    a plausible 8-D state whose gripper fingers differ, episode ``episode-{stream}`` of ``suite`` on stream
    ``stream``."""
    import numpy as np

    from .core import Observation

    rng = np.random.default_rng(step)
    state = np.array([0.1, 0.2, 1.0, 3.1, 0.1, -0.2, 0.04, -0.03])
    return Observation(
        step=step, instruction=instruction, eef_pos=state[:3], eef_quat=np.array([0, 0, 0, 1.0]),
        gripper_qpos=state[6:], state=state, stream=stream, episode_id=f"episode-{stream}", suite=suite,
        agentview_image=rng.integers(0, 256, (256, 256, 3), dtype=np.uint8),
        wrist_image=rng.integers(0, 256, (256, 256, 3), dtype=np.uint8),
    )  # fmt: skip


def start_script_server(script: Path, *args: str, scheme: str, log_dir: Path, name: str | None = None):
    """``python script PORT *args`` (a test's stand-in of an upstream server) on a free port, started once it
    accepts connections; ``(server, "scheme://127.0.0.1:PORT")``. Stop it with ``server.stop()``."""
    import socket

    from .core import ServerProcess, free_port

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
    from .tasks.suite.file import case_line, load_suite

    cases = load_suite().cases
    lines = []
    for suite, task_id, family, level in picks:
        found = next(c for c in cases if (c.suite, c.task_id, c.family, c.level) == (suite, task_id, family, level))
        lines.append(case_line(found) + "\n")
    path.write_text("".join(lines))
    return path


#: Set to 1 to (re)write the golden files :func:`check_pinned_actions` compares with.
RECORD_PINNED_ACTIONS = "CONFLICTBENCH_RECORD_ACTIONS"


def pinned_observations(steps: int = 6) -> list:
    """Two episodes of ``steps`` steps on streams 0 and 1 (other instructions, other sampling seeds), step by
    step in turn, as two workers would send them: the fixed input :func:`check_pinned_actions` plays."""
    texts = ("put the bowl on the plate", "open the top drawer and put the bowl inside")
    return [camera_observation(step, texts[stream], stream=stream) for step in range(steps) for stream in (0, 1)]


def check_pinned_actions(policy, golden: Path, fingerprint: str = "") -> None:
    """Play :func:`pinned_observations` through ``policy`` (started; one ``act`` at a time, so no batch shape or
    arrival order enters) and compare every action bit for bit with the file ``golden``. ``fingerprint`` names
    what the actions come from (a tiny checkpoint's digest): a different one there means the fixture changed,
    not the code. With ``CONFLICTBENCH_RECORD_ACTIONS=1`` in the environment the file is written instead."""
    import os

    import numpy as np

    actions = [np.asarray(policy.act(observation)) for observation in pinned_observations()]
    if os.environ.get(RECORD_PINNED_ACTIONS) == "1":
        golden.parent.mkdir(parents=True, exist_ok=True)
        np.savez(golden, fingerprint=np.array(fingerprint), **{f"action{i}": a for i, a in enumerate(actions)})
        return
    pinned = np.load(golden)
    assert str(pinned["fingerprint"]) == fingerprint, f"the fixture behind {golden.name} changed: re-record it"
    assert len(pinned.files) - 1 == len(actions)
    for i, action in enumerate(actions):
        expected = pinned[f"action{i}"]
        assert action.dtype == expected.dtype and action.shape == expected.shape, (i, action.shape, expected.shape)
        assert action.tobytes() == expected.tobytes(), f"action {i} differs from {golden.name}:\n{action}\n{expected}"
