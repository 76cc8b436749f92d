"""Which of conflictbench's own files a rollout runs: the import closure of its entry points, read from the source.

A rollout runs the run's loop with its simulator workers (:data:`ROLLOUT_ENTRIES`), the modules that define the
policy (a built-in policy's own, or what a plugin imports of conflictbench) and what these import, at the top or
inside a function (a function imported may run). Each package above a module counts with what it imports at its top:
its body runs on the way in, while its functions run only if someone imports its names, an import followed in turn.
The closure does not enter :data:`NOT_ROLLOUT`: modules a run imports that cannot change an episode. Imports are read
from the files with :mod:`ast` (nothing is imported to find out); a data file of conflictbench counts where a module
of the closure names it in quotes (the subject policy's ``SHIPPED`` weights). tests/test_code_identity.py plays a
real run and checks that it imports nothing of conflictbench that this closure and :data:`NOT_ROLLOUT` miss.
"""

from __future__ import annotations

import ast
import functools
import importlib.util
from collections.abc import Iterable
from pathlib import Path
from typing import Any

__all__ = ["NOT_ROLLOUT", "ROLLOUT_ENTRIES", "conflictbench_modules", "imported_conflictbench", "imports_of",
           "policy_modules", "rollout_files", "rollout_modules"]  # fmt: skip

#: Where every rollout starts in conflictbench: the run's loop (it imports the plan, the identity, the policy's
#: calls and the worker pool), the simulator worker (env set-up, observations), and the core's prompt hook (the
#: plugin manager registers it by name).
ROLLOUT_ENTRIES = ("conflictbench.sim.runner", "conflictbench.sim.worker", "conflictbench.core.prompts")
#: What a run imports that cannot change an episode, and why: the closure stops there (with what they import).
NOT_ROLLOUT = {
    "conflictbench.cli": "the command: composes the run (its settings are in the identity) and prints",
    "conflictbench.doctor": "replays shipped golden episodes to check this machine's simulator; plays no run's episode",
    "conflictbench.metrics": "computed from stored episodes, after the rollout",
    "conflictbench.report": "tables and figures from stored episodes",
    "conflictbench.store": "writes and reads episodes; never decides an action",
    "conflictbench.testing": "helpers for tests",
    "conflictbench.view": "the viewer's site, from stored episodes",
    "conflictbench.tasks.suite": "reads, builds and reviews the suite: which cases a run plays; a conflict episode's "
    "id holds its case's id and text and the suite's version",
    "conflictbench.tasks.operators": "the suite's operators write its cases (their text is in their episodes' ids)",
    "conflictbench.tasks.validation": "checks the suite's cases as it is built",
    "conflictbench.sim.code_identity": "says which code an episode's identity holds; decides no action (the "
    "sampling seed takes the versions alone)",
    "conflictbench.sim.rollout_code": "finds the files of that identity",
    "conflictbench.sim.identity_change": "says what changed between a store's identity and this run's",
    "conflictbench.sim.progress": "the progress bar and the run's printed lines",
}
_SKIPPED_PARTS = {"__pycache__", ".pytest_cache"}
_NOT_DATA = (".py", ".pyc", ".swp", ".swo", ".orig", ".rej", ".bak", "~")


def _off_rollout(module: str) -> bool:
    return any(module == name or module.startswith(name + ".") for name in NOT_ROLLOUT)


def _conflictbench() -> tuple[dict[str, Path], dict[str, list[Path]]]:
    """conflictbench's modules by name and its data files by file name, as they are now on disk."""
    modules: dict[str, Path] = {}
    data: dict[str, list[Path]] = {}
    base = Path(importlib.util.find_spec("conflictbench").origin).parent
    for path in sorted(base.rglob("*")):
        parts = path.relative_to(base).parts
        if not path.is_file() or _SKIPPED_PARTS & set(parts) or path.name.startswith("."):
            continue
        if path.suffix == ".py":
            names = ["conflictbench", *parts[:-1]] + ([] if path.stem == "__init__" else [path.stem])
            modules[".".join(names)] = path
        elif not path.name.endswith(_NOT_DATA):
            data.setdefault(path.name, []).append(path)
    return modules, data


@functools.cache
def _parsed(path: Path, stamp: tuple[int, int], package: str) -> tuple[tuple[str, str, bool], ...]:
    """The imports of a file: ``(module, name or "", at its top)``, relative ones made absolute from ``package``
    (cached by the file's modification time and size)."""
    imports: list[tuple[str, str, bool]] = []

    def visit(statements: list[ast.stmt], top: bool) -> None:
        for node in statements:
            if isinstance(node, ast.Import):
                imports.extend((alias.name, "", top) for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                module = node.module or ""
                if node.level:
                    parts = package.split(".")
                    module = ".".join(parts[: len(parts) - node.level + 1] + ([module] if module else []))
                imports.extend((module, alias.name, top) for alias in node.names)
            inner = top and not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
            for block in ("body", "orelse", "finalbody", "handlers", "cases"):
                visit(getattr(node, block, []), inner)

    visit(ast.parse(path.read_bytes(), str(path)).body, True)
    return tuple(imports)


def _read(path: Path, package: str) -> tuple[tuple[str, str, bool], ...]:
    stat = path.stat()
    return _parsed(path, (stat.st_mtime_ns, stat.st_size), package)


def _package(name: str, modules: dict[str, Path]) -> str:
    return name if modules[name].name == "__init__.py" else name.rpartition(".")[0]


def _target(module: str, name: str, modules: dict[str, Path]) -> str:
    """What ``from module import name`` (or ``import module``) loads: the submodule where ``name`` is one; for a
    name that is no file (a former module kept as an alias, ``conflictbench.core.transport``), the package that
    holds it."""
    target = f"{module}.{name}" if name else module
    while target not in modules and "." in target:
        target = target.rpartition(".")[0]
    return target


def imported_conflictbench(files: Iterable[Path]) -> set[str]:
    """The modules of conflictbench that Python files import (a plugin's, anywhere in them)."""
    modules, _ = _conflictbench()
    found = set()
    for path in files:
        if path.suffix == ".py":
            for module, name, _top in _read(path, ""):
                target = _target(module, name, modules)
                if target in modules:
                    found.add(target)
    return found


def conflictbench_modules() -> set[str]:
    """Every module of conflictbench, by name (from its files)."""
    return set(_conflictbench()[0])


def imports_of(module: str, top_only: bool = False) -> set[str]:
    """The modules of conflictbench that ``module`` imports (at its top only, or anywhere in it)."""
    return _imports(module, _conflictbench()[0], top_only)


def _imports(module: str, modules: dict[str, Path], top_only: bool) -> set[str]:
    imports = _read(modules[module], _package(module, modules))
    return {_target(name, imported, modules) for name, imported, top in imports if top or not top_only} & modules.keys()


def rollout_modules(roots: Iterable[str] = (), modules: dict[str, Path] | None = None) -> set[str]:
    """The modules of conflictbench a rollout may run: the closure of :data:`ROLLOUT_ENTRIES` and ``roots``."""
    modules = _conflictbench()[0] if modules is None else modules
    whole: set[str] = set()
    tops: set[str] = set()
    todo = [(root, True) for root in (*ROLLOUT_ENTRIES, *roots)]
    while todo:
        name, all_of_it = todo.pop()
        if name not in modules or _off_rollout(name) or name in whole or (not all_of_it and name in tops):
            continue
        (whole if all_of_it else tops).add(name)
        parts = name.split(".")
        todo.extend((".".join(parts[:i]), False) for i in range(1, len(parts)))
        todo.extend((target, True) for target in _imports(name, modules, top_only=not all_of_it))
    return whole | tops


def rollout_files(roots: Iterable[str] = ()) -> list[tuple[str, Path]]:
    """The files of :func:`rollout_modules`, and the data files they name, by their path from conflictbench's
    parent folder (``conflictbench/sim/worker.py``)."""
    modules, data = _conflictbench()
    files = {modules[name] for name in rollout_modules(roots, modules)}
    texts = [path.read_text(encoding="utf-8") for path in files]
    named = {name for name in data if any(f'"{name}"' in text or f"'{name}'" in text for text in texts)}
    files |= {path for name in named for path in data[name]}
    base = Path(importlib.util.find_spec("conflictbench").origin).parent.parent
    return sorted((path.relative_to(base).as_posix(), path) for path in files)


def policy_modules(spec: Any) -> set[str]:
    """The modules that define a registered policy (``PolicySpec``): its loader, settings and own hooks."""
    found = set()
    for part in (spec.load, spec.config, spec.format_prompt, spec.postprocess):
        part = getattr(part, "func", part)  # a functools.partial
        module = getattr(part, "__module__", None)
        if module is not None:
            found.add(module)
    return found
