"""The command's modules: named apart from what the package uses, a command per verb, each importing on its own (no
import cycle in the command's package or anywhere in conflictbench: tests/test_import_cycles.py)."""

from __future__ import annotations

import ast
import builtins
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import conflictbench.cli
from conflictbench.cli import VERBS

PACKAGE = conflictbench.cli.__name__
ROOT = Path(conflictbench.cli.__file__).parent
MODULES = sorted(p.stem for p in ROOT.glob("*.py"))


def test_no_module_is_named_like_a_name_the_package_uses():
    """Importing conflictbench.cli.X binds X in the package: a module `list` would replace the builtin there."""
    used = {
        node.id
        for node in ast.walk(ast.parse((ROOT / "__init__.py").read_text(encoding="utf-8")))
        if isinstance(node, ast.Name)
    }
    clash = set(MODULES) & (used | set(dir(builtins)))
    assert not clash, f"modules named like a builtin or a name in conflictbench/cli/__init__.py: {sorted(clash)}"


@pytest.mark.parametrize("module", ["run", *VERBS.values()])
def test_every_verb_is_a_module_with_a_command(module):
    assert callable(importlib.import_module(f"{PACKAGE}.{module}").command)


@pytest.mark.parametrize("module", [m for m in MODULES if m != "__main__"])
def test_each_module_imports_alone_in_a_fresh_interpreter(module):
    name = PACKAGE if module == "__init__" else f"{PACKAGE}.{module}"
    out = subprocess.run([sys.executable, "-c", f"import {name}"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
