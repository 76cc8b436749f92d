"""The public API a plugin is written against: every name stays where plugins found it, and the layers stay apart
(``conflictbench.core`` the contract, ``conflictbench.hosting`` the client above it)."""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from itertools import chain
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from testing_support import DEMO_PLUGIN

import conflictbench
import conflictbench.hosting

#: ``conflictbench.__all__`` in 0.2, the names an outside plugin may have been written against.
V0_2_PUBLIC_API = (
    "ActionContext", "ConflictCase", "EpisodeRecord", "Observation", "Pair", "PrivilegedState", "hookimpl",
    "P1_PREAMBLE", "default_format_prompt", "PerEpisode", "rng_for", "sampling_seed", "HttpJsonTransport",
    "InfrastructureError", "PolicyClient", "ServedPolicy", "HostedConfig", "HostedPolicy", "ServerUnavailable",
    "ServingConfig", "Transport", "UserError", "ServerProcess", "free_port", "model_environment",
    "BUILTIN_PLUGINS", "plugins", "__version__",
)  # fmt: skip
#: ``conflictbench.core``'s modules moved to the client layer in 0.3, by their new names.
MOVED_MODULES = {"serving": "client", "transport": "transport", "hosting": "hosted", "launch": "launch"}


def test_every_name_of_0_2_is_still_public_and_every_public_name_exists():
    assert set(V0_2_PUBLIC_API) <= set(conflictbench.__all__)
    assert [name for name in conflictbench.__all__ if not hasattr(conflictbench, name)] == []
    assert [name for name in conflictbench.hosting.__all__ if not hasattr(conflictbench.hosting, name)] == []


def test_an_outside_plugin_written_against_0_2_imports_from_the_old_places():
    """The demo plugin imports the whole of 0.2's API and the moved names from ``conflictbench.core`` and its
    modules, as 0.2's model plugins did; in a fresh interpreter, so nothing imported before helps it. They are the
    moved objects themselves (each use warns until they go in 0.4.0: tests/test_deprecations.py)."""
    probe = (
        "import conflictbench_demo as demo, conflictbench.core as core, conflictbench.hosting as hosting\n"
        "import sys, warnings\n"
        "warnings.simplefilter('ignore', DeprecationWarning)\n"
        "assert core.HostedPolicy is hosting.HostedPolicy and core.ServerProcess is hosting.ServerProcess\n"
        "assert demo._HostedPolicy is hosting.HostedPolicy and demo._LaunchedServerProcess is hosting.ServerProcess\n"
        "assert demo._PolicyClient is hosting.PolicyClient and demo._Transport is hosting.Transport\n"
        f"for old, new in {MOVED_MODULES!r}.items():\n"
        "    moved = sys.modules['conflictbench.hosting.' + new]\n"
        "    assert getattr(core, old) is sys.modules['conflictbench.core.' + old], old\n"
        "    assert all(getattr(getattr(core, old), n) is getattr(moved, n) for n in dir(moved) if n[0] != '_'), old\n"
        "print('ok')\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=DEMO_PLUGIN)
    assert done.returncode == 0 and done.stdout == "ok\n", done.stderr[-2000:]


def test_the_client_layer_imports_only_core_of_ours_and_nothing_heavy():
    """``conflictbench.hosting`` sits on core alone (no simulator, store or runner), so a plugin's client pulls in
    no more than it needs; its protocol modules import their wire library and ``conflictbench_serving`` only."""
    hosting = Path(conflictbench.hosting.__file__).parent
    for path in hosting.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 2:  # from ..core.x import; from .. import core
                names = [node.module] if node.module else [alias.name for alias in node.names]
                assert all(name.split(".")[0] == "core" for name in names), f"{path.name} imports ..{names}"
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                top = node.module.split(".")[0]
                assert top not in {"libero", "robosuite", "mujoco", "torch", "pandas", "hydra"}, path.name
                assert not node.module.startswith("conflictbench.") or node.module.startswith("conflictbench.core")
    done = subprocess.run(
        [sys.executable, "-c", "import sys, conflictbench.hosting; "
         "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'libero', 'mujoco', 'pandas', 'hydra')"
         " or m.startswith(('conflictbench.sim', 'conflictbench.store', 'conflictbench.cli'))))"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert done.stdout.strip() == "[]"


def test_no_model_plugin_imports_or_requires_another():
    """Each plugin stands on conflictbench and conflictbench-serving alone (``scripts/check_wheel.sh`` installs each
    one alone): no module of it, its tests included, imports another plugin's package, and no requirement of it,
    extras included, names another plugin's distribution."""
    projects = {
        folder: tomllib.loads((folder / "pyproject.toml").read_text())["project"]
        for folder in (Path(__file__).resolve().parents[1] / "plugins").iterdir()
        if (folder / "pyproject.toml").is_file()
    }
    packages = {folder: next(folder.glob("conflictbench_*/__init__.py")).parent.name for folder in projects}
    assert len(projects) >= 5
    for folder, project in projects.items():
        other_packages = set(packages.values()) - {packages[folder]}
        for path in folder.rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                assert not {name.split(".")[0] for name in names} & other_packages, f"{path} imports {names}"
        other_dists = {canonicalize_name(p["name"]) for p in projects.values()} - {canonicalize_name(project["name"])}
        requirements = [*project.get("dependencies", []), *chain(*project.get("optional-dependencies", {}).values())]
        assert [r for r in requirements if canonicalize_name(Requirement(r).name) in other_dists] == [], folder.name


def test_each_server_half_is_its_plugins_package_with_the_servers_requirements_and_never_conflictbench():
    """``plugins/NAME/server`` is what a model environment holds: the client's package (not a copy), requiring
    neither conflictbench nor any plugin's client, so every requirement in that environment can be met. Each half
    declares one entry point: the client's module for conflictbench, the server's ``SERVED`` for conflictbench-serve."""
    plugins = Path(__file__).resolve().parents[1] / "plugins"
    served = sorted(folder.name for folder in plugins.iterdir() if list(folder.glob("conflictbench_*/server.py")))
    halves = sorted(folder.name for folder in plugins.iterdir() if (folder / "server" / "pyproject.toml").is_file())
    assert served == halves and len(halves) >= 5  # every plugin with a server has its server half, and only those
    clients = {
        canonicalize_name(tomllib.loads((plugins / n / "pyproject.toml").read_text())["project"]["name"])
        for n in halves
    }
    for name in halves:
        client_toml = tomllib.loads((plugins / name / "pyproject.toml").read_text())
        server_toml = tomllib.loads((plugins / name / "server" / "pyproject.toml").read_text())
        client, server = client_toml["project"], server_toml["project"]
        package = client_toml["tool"]["setuptools"]["packages"]
        assert canonicalize_name(server["name"]) == canonicalize_name(client["name"]) + "-server"
        assert server_toml["tool"]["setuptools"]["packages"] == package
        assert server_toml["tool"]["setuptools"]["package-dir"] == {package[0]: f"../{package[0]}"}
        requirements = [*server["dependencies"], *chain(*server.get("optional-dependencies", {}).values())]
        named = {canonicalize_name(Requirement(r).name) for r in requirements}
        assert "conflictbench-serving" in named and not named & (clients | {"conflictbench"}), name
        entry = next(iter(client["entry-points"]["conflictbench"]))
        assert client["entry-points"] == {"conflictbench": {entry: f"{package[0]}.client"}} and "scripts" not in client
        assert server["entry-points"] == {"conflictbench_serving": {entry: f"{package[0]}.server:SERVED"}}
        assert "optional-dependencies" not in client or not {"server", "server-test"} & set(
            client["optional-dependencies"]
        )
