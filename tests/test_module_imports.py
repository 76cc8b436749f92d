"""What a user imports is declared: every module of conflictbench imports with what the package requires, or says in
one line which of its extras it needs; and nothing outside the tests' helpers needs pytest, or imports them.

``scripts/check_wheel.sh`` walks the installed wheel the same way (``import_every_module.py --strict``), in a fresh
environment holding exactly what the wheel and its extras declare."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

import conflictbench

REPO = Path(__file__).resolve().parents[1]
WALKER = Path(__file__).with_name("import_every_module.py")
PACKAGE = Path(conflictbench.__file__).parent
#: Each protocol module of conflictbench.hosting: the extra it names, and the distributions of what it imports.
PROTOCOL_MODULES = {
    "conflictbench.hosting.openpi": ("openpi", {"websockets", "conflictbench-serving"}),
    "conflictbench.hosting.zeromq": ("zeromq", {"pyzmq", "conflictbench-serving"}),
    "conflictbench.hosting.rest": ("rest", {"json-numpy"}),
    "conflictbench.hosting.openvla_family": ("openvla-family", {"simplejpeg", "pillow"}),
}
#: What those distributions are imported as; blocked, as if none were installed (Pillow stays: matplotlib needs it).
PROTOCOL_IMPORTS = ("websockets", "zmq", "json_numpy", "simplejpeg", "conflictbench_serving")


def declared_extras() -> dict[str, set[str]]:
    """The extras pyproject.toml declares, each with the distributions it requires."""
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    return {name: {canonicalize_name(Requirement(r).name) for r in reqs} for name, reqs in extras.items()}


@pytest.fixture(scope="module")
def walked() -> tuple[subprocess.CompletedProcess, dict[str, dict]]:
    """Every module imported in a Python without pytest and without the protocols' libraries (one process, ~10 s)."""
    blocked = ",".join(("pytest", "_pytest", *PROTOCOL_IMPORTS))
    argv = [sys.executable, str(WALKER), "--strict", "--block", blocked, "--extras", ",".join(declared_extras())]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=600, cwd=REPO)
    return done, {said["module"]: said for said in map(json.loads, done.stdout.splitlines())}


def test_nothing_but_a_protocol_module_needs_what_the_package_does_not_require(walked):
    """Without pytest and the protocols' libraries every module imports (the tests' helpers too: they import pytest
    where a helper needs it), but the four protocol modules, and the one script of another environment."""
    done, said = walked
    assert len(said) > 100, done.stderr[-3000:]
    failed = {name: s["error"] for name, s in said.items() if s["outcome"] == "failed"}
    assert failed == {}
    assert {name for name, s in said.items() if s["outcome"] == "extra"} == set(PROTOCOL_MODULES)
    assert "conflictbench.testing" in said and said["conflictbench.testing"]["outcome"] == "ok"
    # --strict: a module that needs an extra fails the walk, one line each (what check_wheel.sh relies on)
    assert done.returncode == 1 and sorted(done.stderr.splitlines()) == sorted(
        f"{name}: {said[name]['error']}" for name in PROTOCOL_MODULES
    )


@pytest.mark.parametrize("module", sorted(PROTOCOL_MODULES))
def test_a_protocol_module_without_its_extra_says_which_in_one_line(walked, module):
    extra, distributions = PROTOCOL_MODULES[module]
    said = walked[1][module]
    assert said["outcome"] == "extra" and said["extra"] == extra
    assert said["error"].startswith(f"{module} needs conflictbench[{extra}] (No module named ")
    assert f"pip install '.[{extra}]'" in said["error"]
    assert distributions <= declared_extras()[extra]  # the extra brings what the module imports


def _imports_of_the_tests_helpers(path: Path) -> list[str]:
    """The imports in ``path`` (at the top or inside a function) that reach ``conflictbench.testing``."""
    package = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if path.name == "__init__.py":
        package += ".__init__"
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level)[0] if node.level else ""
            module = ".".join(filter(None, [base, node.module or ""]))
            names = [module] if node.module else [f"{module}.{alias.name}" for alias in node.names]
        else:
            continue
        found += [
            name for name in names if name == "conflictbench.testing" or name.startswith("conflictbench.testing.")
        ]
    return found


def test_runtime_code_never_imports_the_tests_helpers():
    """``conflictbench.testing`` is for tests: no other module of conflictbench imports it, at the top or inside a
    function (``doctor model=`` sends ``conflictbench.doctor.observations``' observation, not the tests')."""
    reaching = {
        str(path.relative_to(PACKAGE.parent)): names
        for path in sorted(PACKAGE.rglob("*.py"))
        if "testing" not in path.relative_to(PACKAGE).parts[:1] and (names := _imports_of_the_tests_helpers(path))
    }
    assert reaching == {}
    probe = PACKAGE / "testing" / "observations.py"  # the check sees a relative import of the helpers
    assert _imports_of_the_tests_helpers(probe) == []
    assert _imports_of_the_tests_helpers(PACKAGE / "testing" / "__init__.py")  # from .model_env import ...
