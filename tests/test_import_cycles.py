"""No import cycle in ``conflictbench``: between its modules, counting the imports inside functions and the modules
imported by name at run time, nor between its layers (its subpackages). (That ``conflictbench.core`` imports nothing
else of conflictbench is tests/test_core_plugins.py's.)

Granularity: a module is a ``.py`` file, a package's ``__init__.py`` the package's own module. ``import a.b.c`` and
``from a.b import c`` where ``c`` is a submodule import that submodule (the packages above it run first, but that is
Python's order, not a dependency of the importer); ``from a.b import name`` of any other name imports ``a.b``
itself. So a package's ``__init__`` re-exporting its submodules, and a submodule importing a sibling with
``from . import x``, are no cycle; a submodule importing a name its package's ``__init__`` defines is one.
"""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import conflictbench
from conflictbench.cli import VERBS
from conflictbench.core import FAMILIES
from conflictbench.hosting.former import FORMER_CORE_MODULES
from conflictbench.metrics.registered import BUILTINS_MODULE
from conflictbench.policies import EXPORTS as POLICIES_EXPORTS

PACKAGE = conflictbench.__name__
ROOT = Path(conflictbench.__file__).parent

Graph = dict[str, dict[str, str]]
"""module -> {module it imports: where (``path:line``)}."""


def modules(root: Path, package: str) -> dict[str, Path]:
    """Every module of the package under ``root``, by dotted name (a package by its own name)."""
    found = {}
    for path in sorted(root.rglob("*.py")):
        parts = [package, *path.relative_to(root).with_suffix("").parts]
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imports_of(module: str, path: Path, known: dict[str, Path], package: str) -> dict[str, str]:
    """The modules of ``known`` that ``module`` imports, at the top or inside a function, and where (``path:line``
    from the folder holding the package)."""

    def ours(name: str) -> bool:
        return name == package or name.startswith(package + ".")

    def resolve(name: str) -> str:  # the module a dotted name lives in: itself, or the closest module above it
        while name not in known:
            name = name.rpartition(".")[0]
        return name

    here = module if path.name == "__init__.py" else module.rpartition(".")[0]  # what `from .` means
    found: dict[str, str] = {}
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [resolve(alias.name) for alias in node.names if ours(alias.name)]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = here.split(".")[: len(here.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            if ours(base):
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else resolve(base) for a in node.names]
        for target in targets:
            found.setdefault(target, f"{path.relative_to(known[package].parent.parent)}:{node.lineno}")
    found.pop(module, None)
    return found


def import_graph(root: Path, package: str) -> Graph:
    known = modules(root, package)
    return {module: imports_of(module, path, known, package) for module, path in known.items()}


#: Modules that import others by name, which no import statement shows, and what they import: with
#: ``importlib.import_module`` (the command's verbs, the families' rules), or by giving a plugin manager the built-in
#: plugins' module names (``conflictbench.core.plugins`` imports the names it is given: the edges are the giver's).
BY_NAME = {
    PACKAGE: set(conflictbench.BUILTIN_PLUGINS),  # plugins()
    "conflictbench.sim.demonstrations": set(conflictbench.BUILTIN_PLUGINS),
    "conflictbench.metrics.registered": {BUILTINS_MODULE},  # the default registry of the metrics
    "conflictbench.cli": {f"conflictbench.cli.{verb}" for verb in ["run", *VERBS.values()]},
    "conflictbench.tasks.validation.suite_rules": {f"conflictbench.tasks.validation.{family}" for family in FAMILIES},
    "conflictbench.policies": {f"conflictbench.policies.{module}" for module in POLICIES_EXPORTS.values()},
}
#: The names kept at their places of 0.2 (``hosting/former.py``): read from the modules they moved to, by name.
FORMER = "conflictbench.hosting.former"
BY_NAME[FORMER] = {f"conflictbench.hosting.{new}" for new in FORMER_CORE_MODULES.values()}
#: Modules calling ``importlib.import_module`` with names their callers give (plugins to load, moved names).
IMPORTS_GIVEN_NAMES = {"conflictbench.core.plugins", "conflictbench.core.deprecation"}


@functools.cache  # read once for all the tests here (none changes it)
def package_graph() -> Graph:
    graph = import_graph(ROOT, PACKAGE)
    for module, targets in BY_NAME.items():
        for target in targets & set(graph):  # a family without a module of its own has no rules of its own
            graph[module].setdefault(target, "(imported by name)")
    return graph


def layers(graph: Graph) -> Graph:
    """The graph between conflictbench's subpackages (``conflictbench`` itself is one: the public API)."""

    def layer(module: str) -> str:
        return ".".join(module.split(".")[:2])

    out: Graph = {layer(m): {} for m in graph}
    for module, targets in graph.items():
        for target, where in targets.items():
            if layer(target) != layer(module):
                out[layer(module)].setdefault(layer(target), f"{where} ({module} -> {target})")
    return out


def find_cycle(graph: Graph) -> list[str] | None:
    """One cycle of ``graph`` (its modules in order, the first repeated at the end), or None."""
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


def said(graph: Graph, cycle: list[str]) -> str:
    return " -> ".join([cycle[0]] + [f"{b} ({graph[a][b]})" for a, b in zip(cycle, cycle[1:])])


def test_no_module_of_conflictbench_is_in_an_import_cycle():
    graph = package_graph()
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle: {said(graph, cycle)}"


def test_the_layers_import_each_other_one_way():
    """A subpackage that imports another imports nothing back (``doctor`` below ``cli``, the built-in plugins
    below the runner that plays them), with no module cycle needed for it."""
    graph = layers(package_graph())
    cycle = find_cycle(graph)
    assert cycle is None, f"import cycle between layers: {said(graph, cycle)}"


def by_name_imports(path: Path) -> tuple[bool, bool]:
    """Whether a module calls ``importlib.import_module`` (or ``__import__``), and whether it gives a plugin manager
    built-in plugins (``Plugins(names, ...)`` or ``Plugins(builtins=names)``)."""
    importing = giving = False
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Attribute) and node.attr == "import_module":
            importing = True
        elif isinstance(node, ast.Name) and node.id == "__import__":
            importing = True
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "Plugins":
            giving |= bool(node.args) or any(keyword.arg == "builtins" for keyword in node.keywords)
    return importing, giving


def test_every_import_by_name_is_an_edge_of_the_graph():
    """A new import by name is an edge no import statement shows: it must be listed in ``BY_NAME``."""
    found = {module: by_name_imports(path) for module, path in modules(ROOT, PACKAGE).items()}
    importing = {module for module, (yes, _) in found.items() if yes}
    giving = {module for module, (_, yes) in found.items() if yes}
    assert importing | giving == set(BY_NAME) | IMPORTS_GIVEN_NAMES
    graph = package_graph()
    for module, targets in BY_NAME.items():
        if module != "conflictbench.tasks.validation.suite_rules":  # a family may have no rules of its own
            assert targets <= set(graph), module
    assert BY_NAME["conflictbench.tasks.validation.suite_rules"] & set(graph)


def test_the_cycle_check_finds_a_cycle():
    cycle = {"__init__": {"listing": ""}, "listing": {"run": ""}, "run": {"__init__": ""}}
    assert find_cycle(cycle) == ["__init__", "listing", "run", "__init__"]
    assert find_cycle({"__init__": {"listing": "", "run": ""}, "listing": {"run": ""}, "run": {}}) is None


def write(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text, encoding="utf-8")


def test_the_graph_reads_every_kind_of_import(tmp_path):
    """Relative and absolute, at the top and in a function; ``from package import name`` is the submodule ``name``
    if there is one, else the package's ``__init__``; a package's ``__init__`` re-exporting is no cycle."""
    write(tmp_path / "pkg", {
        "__init__.py": "from .a import A\n",
        "a.py": "A = 1\ndef f():\n    from .sub import thing\n",
        "sub/__init__.py": "from .. import b\nthing = 2\n",
        "sub/leaf.py": "from . import thing\nfrom ..sub import leaf\n",
        "b.py": "import os\nimport pkg.c\nfrom pkg import A\n",
        "c.py": "def g():\n    from .sub.leaf import x\n    import pkg.sub.leaf.x\n",
    })  # fmt: skip
    graph = import_graph(tmp_path / "pkg", "pkg")
    assert {m: set(t) for m, t in graph.items()} == {
        "pkg": {"pkg.a"},
        "pkg.a": {"pkg.sub"},
        "pkg.sub": {"pkg.b"},
        "pkg.sub.leaf": {"pkg.sub"},
        "pkg.b": {"pkg.c", "pkg"},
        "pkg.c": {"pkg.sub.leaf"},
    }
    assert graph["pkg.a"]["pkg.sub"] == "pkg/a.py:3"
    assert find_cycle(graph) == ["pkg", "pkg.a", "pkg.sub", "pkg.b", "pkg"]  # b imports a name of pkg's __init__


def test_the_layer_check_finds_a_cycle_no_module_is_in(tmp_path):
    write(tmp_path / "pkg", {
        "__init__.py": "",
        "sub/__init__.py": "from .. import b\n",
        "sub/leaf.py": "X = 1\n",
        "b.py": "from .sub.leaf import X\n",
    })  # fmt: skip
    graph = import_graph(tmp_path / "pkg", "pkg")
    assert find_cycle(graph) is None
    assert find_cycle(layers(graph)) == ["pkg.b", "pkg.sub", "pkg.b"]
