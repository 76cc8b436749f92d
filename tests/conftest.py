"""Shared fixtures. Simulation tests play real LIBERO episodes through the real runner."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pytest
from testing_support import DEMO_PLUGIN, pip_install_into

import conflictbench
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.runner import Runner, RunResult
from conflictbench.store import EpisodeStore


@pytest.fixture(scope="session")
def plugins():
    return conflictbench.plugins()


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
