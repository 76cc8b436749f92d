"""Shared fixtures. Simulation tests play real LIBERO episodes through the real runner."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest

import conflictbench
from conflictbench.core import ConflictCase
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.runner import Runner, RunResult
from conflictbench.store import EpisodeStore
from conflictbench.tasks.libero.base_tasks import base_task


@pytest.fixture(scope="session")
def plugins():
    return conflictbench.plugins()


def reference_spec(suite: str, task_id: int, init_state: int = 0, prompt: str = "p0") -> EpisodeSpec:
    return EpisodeSpec(suite, task_id, init_state, prompt, base_task(suite, task_id).language)


def conflict_spec(case: ConflictCase, init_state: int = 0, prompt: str = "p0") -> EpisodeSpec:
    return EpisodeSpec(case.suite, case.task_id, init_state, prompt, base_task(case.suite, case.task_id).language, case)


@pytest.fixture
def play(tmp_path: Path, plugins):
    """play(policy_name, specs, settings=None, workers=1, store_dir=None) -> (RunResult, EpisodeStore)."""

    def _play(
        policy: str,
        specs: Sequence[EpisodeSpec],
        settings: dict | None = None,
        workers: int = 1,
        store_dir: Path | None = None,
        plugin_set=None,
    ) -> tuple[RunResult, EpisodeStore]:
        pl = plugin_set or plugins
        spec = pl.policy(policy)
        store = EpisodeStore(store_dir or tmp_path / "store")
        runner = Runner(pl, spec, spec.make_config(settings or {}), store=store, workers=workers, progress=False)
        return runner.run(list(specs)), store

    return _play


DEMO_PLUGIN = Path(__file__).parent / "plugins" / "conflictbench-demo"


def pip_install_into(target: Path, source: Path, upgrade: bool = False) -> Path:
    """Install a plugin's source folder into ``target`` as a real distribution (its entry points found
    from ``PYTHONPATH`` or ``sys.path``), without touching the test environment."""
    import subprocess
    import sys

    command = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--no-compile"]
    subprocess.run([*command, *(["--upgrade"] if upgrade else []), "--target", str(target), str(source)], check=True)
    return target


@pytest.fixture(scope="session")
def demo_plugin_site(tmp_path_factory) -> Path:
    """The demo plugin, pip-installed (a real distribution with a real entry point) into a directory."""

    target = tmp_path_factory.mktemp("demo-plugin-site")
    pip_install_into(target, DEMO_PLUGIN)
    return target


@pytest.fixture
def cli(tmp_path: Path, demo_plugin_site: Path):
    """cli(*args, timeout=...) runs the installed `conflictbench` command in tmp_path, demo plugin visible."""
    import os
    import subprocess
    import sys

    exe = Path(sys.executable).parent / "conflictbench"

    def _cli(*args: str, timeout: float = 600, cwd: Path | None = None) -> subprocess.CompletedProcess:
        env = {**os.environ, "PYTHONPATH": str(demo_plugin_site)}
        return subprocess.run(
            [str(exe), *args],
            cwd=cwd or tmp_path,
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
            stdin=subprocess.DEVNULL,
        )

    return _cli
