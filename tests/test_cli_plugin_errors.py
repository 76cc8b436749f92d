"""A broken third-party plugin is reported by the command in one line naming it (exit 2), never a traceback."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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


def test_a_misspelled_hook_in_an_installed_plugin_stops_the_command_with_one_line(tmp_path: Path):
    source = tmp_path / "conflictbench-typo"
    (source / "conflictbench_typo").mkdir(parents=True)
    (source / "pyproject.toml").write_text(PYPROJECT)
    (source / "conflictbench_typo" / "__init__.py").write_text(MODULE)
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                    "--no-compile", "--target", str(site), str(source)], check=True)
    exe = Path(sys.executable).parent / "conflictbench"
    done = subprocess.run([str(exe), "list"], env={**os.environ, "PYTHONPATH": str(site)}, capture_output=True,
                          text=True, timeout=300, stdin=subprocess.DEVNULL)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert "plugin typo (conflictbench-typo)" in lines[0]
    assert "unknown hook 'conflictbench_register_policy' (did you mean conflictbench_register_policies?)" in lines[0]
