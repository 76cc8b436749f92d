"""Whole runs with a tiny π0.5: real LIBERO episodes, our server in the model environment, the CLI as users call it."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from server_fixtures import model_process_env, server_argv
from tiny_fixtures import MODEL_PYTHON, TINY_DIR, needs_model_env

from conflictbench.hosting import ServerProcess, free_port
from conflictbench.store import EpisodeStore
from conflictbench.store.declarations import declarations
from conflictbench.testing import episode_counts as counts
from conflictbench.testing import run_cli as run_cli_on_one_case

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real episodes through the command
STEPS = 15  # three queries of five actions per episode


def run_cli(tmp_path: Path, env: dict[str, str], *overrides: str, out: str = "results") -> subprocess.CompletedProcess:
    settings = ["model=pi05", f"model.max_steps={STEPS}", *overrides]
    return run_cli_on_one_case(tmp_path, *settings, out=out, env=model_process_env(env))


def our_server(checkpoint: Path, env: dict[str, str], port: int, max_batch: int = 32) -> ServerProcess:
    return ServerProcess(
        server_argv("ours", checkpoint, port, max_batch),
        name="pi0-test",
        health_url=f"http://127.0.0.1:{port}/healthz",
        env=model_process_env(env),
        startup_timeout_s=240,
    ).start()


def actions_by_episode(root: Path) -> dict[str, np.ndarray]:
    return {r.episode_id: r.raw_actions for r in EpisodeStore(root).records()}


@needs_model_env
def test_a_checkpoint_gets_its_own_server_for_the_run_and_real_episodes_play(tmp_path, tiny_checkpoints, tiny_env):
    checkpoint = tiny_checkpoints["pi05"]
    settings = [f"model.checkpoint={checkpoint}", "model.device=cpu", "model.max_batch=2", "prompt=p1"]
    out = run_cli(tmp_path, tiny_env, *settings, "run.workers=2")
    assert out.returncode == 0, out.stderr[-3000:]
    assert counts(out.stderr) == (2, 0, 0)
    log = Path(re.search(r"\(log: (\S+)\)", out.stderr)[1])
    assert f"serving pi05 from {checkpoint}" in log.read_text()
    alive = subprocess.run(["pgrep", "-f", "--", f"--checkpoint {checkpoint}"], capture_output=True, text=True)
    assert alive.returncode == 1 and alive.stdout == "", f"the run left its server running: {alive}"
    records = list(EpisodeStore(tmp_path / "results").records())
    for record in records:
        assert record.steps == STEPS and record.error is None and record.prompt == "p1"
        # the model environment's stack, read from its files before the server started
        assert record.model_stack[0] == "device=cpu" and any(p.startswith("lerobot==") for p in record.model_stack)
        assert np.ptp(record.raw_actions[:, :6], axis=0).min() > 0  # the model's actions move, step to step
    assert not np.allclose(records[0].raw_actions, records[1].raw_actions)  # the prompt reached the model

    again = run_cli(tmp_path, tiny_env, *settings)
    assert again.returncode == 0 and counts(again.stderr) == (0, 2, 0), again.stderr[-3000:]


@needs_model_env
def test_one_or_two_workers_play_the_same_actions(tmp_path, tiny_checkpoints, tiny_env):
    """Whoever shares a batched call, an episode's actions are the same. (Another batch shape is another identity,
    so other episodes: test_pi0_client.py::test_a_checkpoint_counts_by_its_content_and_settings_by_whether_they_change_
    actions, with test_policy_lifecycle.py::test_the_identity_a_policy_declares_is_part_of_every_episode_identity.)"""
    checkpoint = tiny_checkpoints["pi05"]
    label = ["model.checkpoint=tiny-pi05", "run.init_states=2"]  # 4 episodes: 2 references, 2 conflicts
    batching = our_server(checkpoint, tiny_env, free_port(), max_batch=2)
    try:
        url = f"ws://127.0.0.1:{batching.health_url.split(':')[2].split('/')[0]}"
        one = run_cli(tmp_path, tiny_env, f"model.server={url}", "run.workers=1", *label, out="one")
        two = run_cli(tmp_path, tiny_env, f"model.server={url}", "run.workers=2", *label, out="two")
    finally:
        batching.stop()
    for out in (one, two):
        assert out.returncode == 0 and counts(out.stderr) == (4, 0, 0), out.stderr[-3000:]
    runs = [actions_by_episode(tmp_path / name) for name in ("one", "two")]
    assert runs[0].keys() == runs[1].keys() and len(runs[0]) == 4  # the same episodes ...
    for episode, actions in runs[0].items():
        assert actions.shape == (STEPS, 7)
        np.testing.assert_array_equal(runs[1][episode], actions)  # ... bit for bit, whoever shared a call


@needs_model_env
@pytest.mark.parametrize("name", ["pi0", "pi05"])
def test_the_served_path_gives_the_actions_of_a_direct_lerobot_call(tmp_path, tiny_checkpoints, tiny_env, name):
    """Client processing, wire, our server and backend, against LeRobot called alone on the same input."""
    from test_pi0_client import observation

    from conflictbench_pi0.client import PiConfig, load
    from conflictbench_pi0.protocol import packb

    observations = [
        observation(step=step, episode=f"{name}-e", prompt=f"put the bowl on plate {step}") for step in (0, 7)
    ]
    server = our_server(tiny_checkpoints[name], tiny_env, port := free_port(), max_batch=1)  # LeRobot's shape
    try:
        policy = load(name, PiConfig(server=f"ws://127.0.0.1:{port}", checkpoint="tiny"))
        try:
            served = [policy.act(obs) for obs in observations]
            requests = [policy.encode(obs) for obs in observations]
        finally:
            policy.close()
    finally:
        server.stop()
    (tmp_path / "requests.msgpack").write_bytes(packb(requests))
    direct = subprocess.run(
        [str(MODEL_PYTHON), str(TINY_DIR / "direct.py"), "--checkpoint", str(tiny_checkpoints[name])]
        + ["--requests", str(tmp_path / "requests.msgpack"), "--out", str(tmp_path / "direct.npz")],
        env=model_process_env(tiny_env), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert direct.returncode == 0, direct.stdout[-2000:] + direct.stderr[-2000:]
    expected = np.load(tmp_path / "direct.npz")["actions"]
    for got, want in zip(served, expected):
        assert got.shape == (5, 7)
        np.testing.assert_array_equal(got, want[:5])
    assert not np.allclose(served[0], served[1])


@needs_model_env
def test_a_quick_reproduce_of_a_tiny_checkpoint_prints_the_published_figure_and_an_inconclusive_verdict(
    tmp_path, tiny_checkpoints, tiny_env
):
    """The path and the table with a real plugin: the tiny π0.5's server, real episodes, the pi05-libero entry."""
    import conflictbench

    entry = conflictbench.plugins().published_results()["pi05-libero"]
    argv = [sys.executable, "-m", "conflictbench.cli", "reproduce", "model=pi05", "model.published=pi05-libero",
            f"model.checkpoint={tiny_checkpoints['pi05']}", "model.device=cpu", f"model.max_steps={STEPS}",
            "--quick", "run.tasks=[libero_spatial/0]", "run.progress=false",
            f"run.out={tmp_path / 'store'}"]  # fmt: skip
    done = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, env=model_process_env(tiny_env),
                          stdin=subprocess.DEVNULL, timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert counts(done.stderr) == (2, 0, 0)  # the first two initial states of the one task asked for
    line = next(line for line in done.stdout.splitlines() if line.startswith("libero_spatial "))
    assert f"{entry.success['libero_spatial']:.1f}" in line and line.split()[-1] == "inconclusive"
    assert entry.url in done.stdout  # the citation under the table
    assert (tmp_path / "store" / "report" / "reproduce-pi05-libero.csv").is_file()
    assert list(declarations(tmp_path / "store").values()) == ["pi05-libero"]
