"""Shared fixtures. Simulation tests play real LIBERO episodes through the real runner."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest
from testing_support import DEMO_PLUGIN, pip_install_into

import conflictbench
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.runner import Runner, RunResult
from conflictbench.store import EpisodeStore

# Tests start hundreds of short runs, each in new processes that would compile their scenes again (~5 s each): a
# shared cache of compiled models (conflictbench/sim/compiled_models.py) loads them instead. .ci/run sets it for
# every stage (the plugins' tests too); set it yourself to move it, or to an empty value to compile every time.
os.environ.setdefault("CONFLICTBENCH_MODEL_CACHE", str(Path.home() / ".cache" / "conflictbench" / "compiled-models"))

# Where PYTHONDONTWRITEBYTECODE is set (these machines set it) and uv installed no bytecode, each of the hundreds of
# processes the tests start (workers, servers, the CLI) compiled LIBERO's, torch's and our modules from source:
# importing the simulator side took 3.3 s, 1.2 s with caches. The first process to import a module writes its cache
# (as .ci/run does; CPython writes it atomically and checks the source's time and size before using one).
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
sys.dont_write_bytecode = False


def _not_pytests(handlers: list[logging.Handler]) -> set[logging.Handler]:
    return {handler for handler in handlers if not type(handler).__module__.startswith("_pytest")}


@pytest.fixture(autouse=True)
def _root_logger_left_as_found():
    """A run in-process (Hydra sets up the root logger: INFO, onto the output pytest captured for that test) left
    later tests' servers logging into a closed stream: pages of "--- Logging error ---" in a failure's output."""
    root = logging.getLogger()
    before, level = _not_pytests(root.handlers), root.level
    yield
    after = _not_pytests(root.handlers)  # pytest's own capture handlers come and go with each phase: not ours
    for handler in after - before:
        root.removeHandler(handler)
        handler.close()  # Hydra's file handler holds the run's log open
    for handler in before - after:  # Hydra's set-up first removes every handler the root had
        root.addHandler(handler)
    root.setLevel(level)


@pytest.fixture(scope="session")
def plugins():
    return conflictbench.plugins()


@pytest.fixture
def play(tmp_path: Path, plugins):
    """play(policy, specs, settings=None, workers=1, store_dir=None, max_steps=None) -> (RunResult, EpisodeStore)."""

    def _play(
        policy: str,
        specs: Sequence[EpisodeSpec],
        settings: dict | None = None,
        workers: int = 1,
        store_dir: Path | None = None,
        plugin_set=None,
        max_steps: int | None = None,
    ) -> tuple[RunResult, EpisodeStore]:
        pl = plugin_set or plugins
        spec = pl.policy(policy)
        store = EpisodeStore(store_dir or tmp_path / "store")
        runner = Runner(
            pl,
            spec,
            spec.make_config(settings or {}),
            store=store,
            workers=workers,
            progress=False,
            max_steps=max_steps,
        )
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
