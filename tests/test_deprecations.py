"""Names kept at their former places for one version (until 0.4.0): each use warns with a ``DeprecationWarning`` that
names the new place and blames the line that used it, and still gives the same object; the new places never warn.
CHANGELOG.md lists them."""

from __future__ import annotations

import importlib
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import conflictbench.core
import conflictbench.hosting
from conflictbench.hosting import HostedConfig, HostedPolicy, HttpJsonTransport
from conflictbench.hosting.former import FORMER_CORE_MODULES, FORMER_CORE_NAMES, REMOVED_IN

#: A name each former core module held, read through its stand-in.
A_NAME_OF = {"client": "PolicyClient", "transport": "one_line", "hosted": "HostedPolicy", "launch": "ServerProcess"}


#: This project's model plugins (client halves), by distribution name: the ones whose code these tests answer for.
PROJECT_DISTRIBUTIONS = sorted(
    tomllib.loads(path.read_text(encoding="utf-8"))["project"]["name"]
    for path in (Path(__file__).resolve().parents[1] / "plugins").glob("*/pyproject.toml")
)


def python(code: str, *flags: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *flags, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("name", FORMER_CORE_NAMES)
def test_a_name_of_the_former_core_warns_and_is_the_moved_object(name):
    with pytest.warns(DeprecationWarning, match=rf"conflictbench\.core\.{name} .*{REMOVED_IN}.*conflictbench\.hosting"):
        value = getattr(conflictbench.core, name)
    assert value is getattr(conflictbench.hosting, name)


@pytest.mark.parametrize("old", sorted(FORMER_CORE_MODULES))
def test_a_former_core_module_warns_on_each_name_read_and_gives_the_moved_modules(old):
    new = f"conflictbench.hosting.{FORMER_CORE_MODULES[old]}"
    stand_in = importlib.import_module(f"conflictbench.core.{old}")
    assert getattr(conflictbench.core, old) is stand_in
    name = A_NAME_OF[FORMER_CORE_MODULES[old]]
    with pytest.warns(DeprecationWarning, match=rf"conflictbench\.core\.{old}\.{name} .*import {name} from {new}$"):
        value = getattr(stand_in, name)
    assert value is getattr(importlib.import_module(new), name)


def test_an_old_import_is_blamed_on_the_line_that_wrote_it_and_is_an_error_under_W_error():
    """Python shows a DeprecationWarning by default where ``__main__``'s code triggered it: the warning must name that
    line, not conflictbench's (nor the import system's) own."""
    code = "import conflictbench\nfrom conflictbench.core.serving import PolicyClient\n"
    shown = python(code)
    assert shown.returncode == 0
    assert shown.stderr.startswith("<string>:2: DeprecationWarning: conflictbench.core.serving.PolicyClient is "), (
        shown.stderr
    )
    assert "import PolicyClient from conflictbench.hosting.client" in shown.stderr
    shown = python("from conflictbench.core import HostedPolicy")  # through the import system's from-list
    assert shown.stderr.startswith("<string>:1: DeprecationWarning: conflictbench.core.HostedPolicy"), shown.stderr
    refused = python(code, "-W", "error::DeprecationWarning")
    assert refused.returncode == 1 and "DeprecationWarning: conflictbench.core.serving.PolicyClient" in refused.stderr


def test_the_new_places_do_not_warn():
    code = (
        "import conflictbench, conflictbench.core, conflictbench.hosting\n"
        "from conflictbench import *\nfrom conflictbench.core import *\nfrom conflictbench.hosting import *\n"
        "from conflictbench.hosting import client, hosted, launch, transport, openpi, zeromq, rest, openvla_family\n"
        "from conflictbench.hosting.client import PolicyClient\n"
        "from conflictbench_serving.command import ServedModel, main\n"
        # this project's plugins load without an old name (what else is installed here may use them)
        f"project = {PROJECT_DISTRIBUTIONS!r}\n"
        "failures = conflictbench.plugins().load_failures.items()\n"
        "failed = {k: v for k, v in failures if k.split(' (')[1][:-1] in project}\n"
        "print(failed or 'quiet')\n"
    )
    done = python(code, "-W", "error::DeprecationWarning")
    assert done.returncode == 0 and done.stdout == "quiet\n", done.stdout + done.stderr[-3000:]


def test_hosted_policy_server_module_warns_where_declared_and_still_hosts():
    with pytest.warns(DeprecationWarning, match=r"\.Old\.server_module .*0\.4\.0: declare served = ServedModel\.of"):

        class Old(HostedPolicy):
            environment = "old"
            server_module = "old_server"
            transport = HttpJsonTransport

    assert Old.model_environment_name() == "old"
    policy = Old.__new__(Old)
    policy.name, policy.cfg = "old-policy", HostedConfig()
    assert policy.server_command() == ["-m", "old_server", "serve", "--policy", "old-policy"]


@pytest.mark.parametrize(
    ("module", "name", "new"),
    [
        ("conflictbench_pi0.transport", "OpenpiTransport", "conflictbench.hosting.openpi:OpenpiTransport"),
        ("conflictbench_gr00t.transport", "Gr00tTransport", "conflictbench.hosting.zeromq:ZmqTransport"),
        ("conflictbench_gr00t.transport", "answers_ping", "conflictbench.hosting.zeromq:answers_ping"),
    ],
)
def test_a_plugins_transport_re_export_warns_and_is_the_hosting_modules(module, name, new):
    old = pytest.importorskip(module)  # where the plugin is installed
    where, _, attribute = new.partition(":")
    with pytest.warns(DeprecationWarning, match=rf"{module}\.{name} .*import {attribute} from {where}$"):
        value = getattr(old, name)
    assert value is getattr(importlib.import_module(where), attribute)
    with pytest.raises(AttributeError, match="has no attribute 'nothing'"):
        old.nothing  # noqa: B018


def test_a_plugins_own_command_warns_naming_conflictbench_serve():
    """``conflictbench-NAME serve ...`` (a console script) and ``python -m conflictbench_NAME`` run ``plugin_main``
    from their ``__main__``: the warning shows without any flag, before the command does its work."""
    done = python("import sys\nfrom conflictbench_serving.command import plugin_main\n"
                  "sys.exit(plugin_main('conflictbench-nothing', ['serve']))")  # fmt: skip
    first, *rest = done.stderr.splitlines()
    assert first.startswith("<string>:3: DeprecationWarning: conflictbench-nothing serve --policy POLICY is deprecated")
    assert "use conflictbench-serve POLICY with the same options" in first
    assert done.returncode == 2 and rest[-1] == (
        "conflictbench-nothing: no installed plugin declares 'nothing' in the conflictbench_serving group"
    )


def test_patching_a_name_at_its_former_place_patches_what_runs(monkeypatch):
    """A plugin's tests of 0.2 that patch ``conflictbench.core.launch.free_port`` still patch the function the code
    calls (the moved module's), with a warning; and undoing the patch restores it."""
    stand_in = importlib.import_module("conflictbench.core.launch")
    moved = importlib.import_module("conflictbench.hosting.launch")
    original = moved.free_port
    with pytest.warns(
        DeprecationWarning, match=r"conflictbench\.core\.launch\.free_port .*conflictbench\.hosting\.launch"
    ):
        monkeypatch.setattr(stand_in, "free_port", lambda: 1)
    assert moved.free_port() == 1
    with pytest.warns(DeprecationWarning):
        monkeypatch.undo()
    assert moved.free_port is original
