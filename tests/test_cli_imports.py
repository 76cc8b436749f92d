"""The command's package has no import cycle, and each of its modules imports on its own."""

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


def module_of(name: str) -> str | None:
    """The module of the package that an imported dotted name lives in, if any."""
    if name == PACKAGE:
        return "__init__"
    if name.startswith(PACKAGE + "."):
        first = name[len(PACKAGE) + 1 :].split(".")[0]
        return first if first in MODULES else "__init__"  # a submodule, or a name defined in __init__
    return None


def cli_imports(module: str) -> set[str]:
    """The modules of the package that ``module`` imports, at the top or inside a function."""
    found: set[str | None] = set()
    for node in ast.walk(ast.parse((ROOT / f"{module}.py").read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found |= {module_of(alias.name) for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative to this package
                base = ".".join(filter(None, [PACKAGE.rsplit(".", node.level - 1)[0], base]))
            found |= {module_of(f"{base}.{alias.name}") for alias in node.names}
    return found - {None, module}


def import_graph() -> dict[str, set[str]]:
    graph = {module: cli_imports(module) for module in MODULES}
    graph["__init__"] |= {"run", *VERBS.values()}  # main() imports the verb's module by name
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    done: set[str] = set()

    def visit(module: str, path: list[str]) -> list[str] | None:
        if module in path:
            return path[path.index(module) :] + [module]
        if module in done:
            return None
        for target in sorted(graph[module]):
            if cycle := visit(target, [*path, module]):
                return cycle
        done.add(module)
        return None

    return next((c for m in sorted(graph) if (c := visit(m, []))), None)


def test_the_package_has_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, f"import cycle in {PACKAGE}: {' -> '.join(cycle)}"


def test_the_cycle_check_finds_a_cycle():
    cycle = {"__init__": {"listing"}, "listing": {"run"}, "run": {"__init__"}}
    assert find_cycle(cycle) == ["__init__", "listing", "run", "__init__"]
    assert find_cycle({"__init__": {"listing", "run"}, "listing": {"run"}, "run": set()}) is None


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
