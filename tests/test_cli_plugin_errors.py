"""A broken third-party plugin is reported by the command in one line naming it (exit 2), never a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from testing_support import pip_install_into

PYPROJECT = """[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "conflictbench-typo"
version = "1.0"
description = "A plugin with a misspelled hook"

[project.entry-points.conflictbench]
typo = "conflictbench_typo"

[tool.setuptools]
packages = ["conflictbench_typo"]
"""

MODULE = """from conflictbench import hookimpl

@hookimpl
def conflictbench_register_policy(register):   # misspelled: the hook is conflictbench_register_policies
    register("typo-policy", load=lambda cfg: None)
"""


def install(tmp_path: Path, module: str, version: str = "1.0", site: Path | None = None) -> Path:
    """The plugin as a real distribution, pip-installed into a directory (default: a fresh one)."""
    source = tmp_path / f"conflictbench-typo-{version}"
    (source / "conflictbench_typo").mkdir(parents=True)
    (source / "pyproject.toml").write_text(PYPROJECT.replace('version = "1.0"', f'version = "{version}"'))
    (source / "conflictbench_typo" / "__init__.py").write_text(module)
    site = site or tmp_path / "site"
    pip_install_into(site, source, upgrade=True)
    return site


def conflictbench(site: Path, *args: str) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "conflictbench"
    return subprocess.run(
        [str(exe), *args],
        env={**os.environ, "PYTHONPATH": str(site)},
        capture_output=True,
        text=True,
        timeout=300,
        stdin=subprocess.DEVNULL,
    )


def test_a_misspelled_hook_in_an_installed_plugin_stops_the_command_with_one_line(tmp_path: Path):
    done = conflictbench(install(tmp_path, MODULE), "list")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert "plugin typo (conflictbench-typo)" in lines[0]
    assert "unknown hook 'conflictbench_register_policy' (did you mean conflictbench_register_policies?)" in lines[0]


CLIP = """import numpy as np
from conflictbench import hookimpl

@hookimpl
def conflictbench_postprocess_action(action, context):
    return np.clip(action, -0.9, 0.9)
"""


def test_list_names_the_plugins_whose_global_hooks_touch_every_policy(tmp_path: Path):
    done = conflictbench(install(tmp_path, CLIP), "list")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("global hooks"))
    assert lines[start + 1].split() == ["conflictbench-typo==1.0", "conflictbench_postprocess_action"]


def test_a_plugin_installed_twice_in_two_versions_is_refused(tmp_path: Path):
    site = install(tmp_path, CLIP, "1.0")
    install(tmp_path, CLIP, "1.1", site=site)  # pip --target --upgrade leaves both dist-info folders
    assert len(list(site.glob("conflictbench_typo-*.dist-info"))) == 2
    done = conflictbench(site, "list")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert "conflictbench-typo is installed more than once (1.0, 1.1)" in done.stderr


def test_a_disabled_plugin_is_never_imported_and_list_shows_it_disabled(tmp_path: Path):
    broken = install(tmp_path, MODULE)  # its misspelled hook would stop every command
    done = conflictbench(broken, "--disable-plugins", "typo", "list")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    start = lines.index("plugins disabled (--disable-plugins, CONFLICTBENCH_DISABLE_PLUGINS; not imported):")
    assert lines[start + 1].split() == ["typo", "conflictbench-typo", "1.0"]
    assert "typo-policy" not in done.stdout


def test_the_variable_disables_a_global_hook_by_its_distribution_name_and_a_wrong_name_is_one_line(
    tmp_path: Path, monkeypatch
):
    site = install(tmp_path, CLIP)
    monkeypatch.setenv("CONFLICTBENCH_DISABLE_PLUGINS", "Conflictbench_Typo")
    done = conflictbench(site, "list")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("global hooks"))
    assert lines[start + 1].strip() == "(none installed)"
    monkeypatch.setenv("CONFLICTBENCH_DISABLE_PLUGINS", "clip")
    done = conflictbench(site, "list")
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert "cannot disable clip: no installed plugin has that entry-point or distribution name" in done.stderr
    assert "conflictbench-typo" in done.stderr
