"""The code in an episode's identity is the files' content: an edit makes stored episodes stale, a version does not
hide one, and only the code a rollout of that policy runs counts."""

from __future__ import annotations

import importlib.metadata as metadata
import os
from pathlib import Path

import pytest

import conflictbench
from conflictbench.sim.code_identity import code_identity, code_pins, distribution_files
from conflictbench.sim.identity_change import code_changes, keep_manifests
from conflictbench.sim.rollout_code import (
    NOT_ROLLOUT,
    ROLLOUT_ENTRIES,
    conflictbench_modules,
    imports_of,
    policy_modules,
    rollout_modules,
)

SUITE_BUILDING = ("conflictbench.tasks.operators", "conflictbench.tasks.validation", "conflictbench.tasks.scene")


@pytest.fixture(scope="module")
def builtins():
    return conflictbench.plugins(entry_points=False)


def under(modules, *packages: str) -> list[str]:
    return sorted(m for m in modules if any(m == p or m.startswith(p + ".") for p in packages))


def test_what_a_rollout_is_said_not_to_run_is_there_and_is_no_entry():
    assert [name for name in NOT_ROLLOUT if not under(conflictbench_modules(), name)] == []
    assert not under(ROLLOUT_ENTRIES, *NOT_ROLLOUT)


def test_a_built_in_policys_rollout_runs_the_loop_the_workers_and_that_policy_not_the_suites_building(builtins):
    modules = rollout_modules(policy_modules(builtins.policy("scripted")))
    assert {"conflictbench.sim.runner", "conflictbench.sim.worker", "conflictbench.sim.capture",
            "conflictbench.sim.libero_env", "conflictbench.tasks.libero.base_tasks", "conflictbench.core.prompts",
            "conflictbench.policies.scripted.grasp"} <= modules  # fmt: skip
    assert under(modules, *SUITE_BUILDING, *NOT_ROLLOUT, "conflictbench.hosting.openvla_family") == []
    names = {name for name, _ in distribution_files("conflictbench", policy_modules(builtins.policy("subject")))}
    assert {"conflictbench/sim/worker.py", "conflictbench/policies/subject/subject.npz"} <= names
    assert "conflictbench/hosting/client.py" in names and "conflictbench/core/prompts.py" in names
    assert not [n for n in names if n.split("/")[1] in ("report", "view", "store", "cli", "metrics")]
    assert not [n for n in names if n.startswith(("conflictbench/tasks/data/", "conflictbench/tasks/operators"))]
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]


def test_what_a_plugin_imports_of_conflictbench_counts_for_its_own_episodes_only(tmp_path, monkeypatch, builtins):
    package = fake_distribution(tmp_path, "lab-policy", "1.0", [])
    (package / "client.py").write_text(
        "def steps():\n    from conflictbench.hosting.openvla_family import center_crop\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    lab = code_identity(["lab-policy==1.0", "conflictbench==0.2.0"])[1]
    (own,) = [hashes for pin, hashes in lab.items() if pin.startswith("conflictbench==")]
    assert "conflictbench/hosting/openvla_family.py" in own and "conflictbench/sim/runner.py" in own
    assert not [name for name in own if name.startswith("conflictbench/policies/")]  # the built-in policies
    scripted = code_identity(["conflictbench==0.2.0"], builtins.policy("scripted"))[1]
    (own,) = scripted.values()
    assert "conflictbench/hosting/openvla_family.py" not in own and "conflictbench/policies/scripted/grasp.py" in own


#: The built-in policies other than the one the real run below plays (noop).
OTHER_BUILTINS = ("random", "scripted", "oracle", "subject")


@pytest.mark.sim
def test_a_real_run_imports_nothing_of_conflictbench_that_the_closure_misses(tmp_path, builtins):
    """Every module of conflictbench a run imports, in any of its processes, is one its rollout may run, or one
    that only what cannot change an episode (:data:`NOT_ROLLOUT`) imports; the suite's building is not imported."""
    from conflictbench.testing.runs import episode_counts, run_cli

    seen = tmp_path / "imported"
    seen.mkdir()
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "sitecustomize.py").write_text(RECORD_IMPORTS.replace("SEEN", repr(str(seen))))
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(seen.parent / "site"), os.environ.get("PYTHONPATH")])),
    }
    # The built-ins alone: what a plugin imports of conflictbench counts for its own episodes (the test above).
    env["CONFLICTBENCH_DISABLE_PLUGINS"] = ",".join(e.name for e in metadata.entry_points(group="conflictbench"))
    done = run_cli(tmp_path, "model=noop", "run.cases_per_cell=0", "run.tasks=[libero_spatial/0]", env=env, max_steps=1)
    assert done.returncode == 0 and episode_counts(done.stderr) == (1, 0, 0), done.stderr[-2000:]
    imported = {name for f in seen.iterdir() for name in f.read_text().split()} & conflictbench_modules()
    assert {"conflictbench.sim.worker", "conflictbench.sim.capture", "conflictbench.policies.simple"} <= imported
    rollout = rollout_modules(policy_modules(builtins.policy("noop")))
    # What a module the rollout does not run imports is no rollout's either (the command's own helpers).
    off_rollout = {target for module in imported - rollout for target in imports_of(module)}
    # Registering the built-ins imports each one's module; only the played one's code runs in its episodes.
    others = set().union(*(rollout_modules(policy_modules(builtins.policy(name))) for name in OTHER_BUILTINS))
    assert sorted(imported - rollout - off_rollout - others - set(under(imported, *NOT_ROLLOUT))) == []
    assert {"conflictbench.policies.subject.policy", "conflictbench.policies.scripted"} <= imported - rollout
    assert under(imported, *SUITE_BUILDING) == []


#: A sitecustomize that writes down each module of conflictbench as a process imports it, one file per process.
RECORD_IMPORTS = """
import os, sys
class _Seen:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "conflictbench":
            with open(os.path.join(SEEN, str(os.getpid())), "a") as f:
                f.write(name + "\\n")
sys.meta_path.insert(0, _Seen())
"""


def fake_distribution(site: Path, name: str, version: str, requires: list[str]) -> Path:
    """An installed distribution ``name`` (package ``name`` with a processing module), as pip or an editable
    install leaves it: the package's files and a dist-info with its top-level names and requirements."""
    package = site / name.replace("-", "_")
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "processing.py").write_text("SCALE = 1.0\n")
    info = site / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    lines = [f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"] + [f"Requires-Dist: {r}\n" for r in requires]
    (info / "METADATA").write_text("".join(lines))
    (info / "top_level.txt").write_text(name.replace("-", "_") + "\n")
    return package


def test_one_edited_line_of_a_plugins_processing_is_other_code_under_the_same_version(tmp_path, monkeypatch):
    package = fake_distribution(tmp_path, "lab-policy", "1.0", ["conflictbench-serving>=0.1", "numpy; extra == 'x'"])
    monkeypatch.syspath_prepend(str(tmp_path))
    before = code_pins(["lab-policy==1.0", "conflictbench==0.2.0", "(in-process)==unknown"])
    names = [pin.split("==")[0] for pin in before]
    # The plugin, what it requires of ours (its server half), the core; an in-process plugin as it was given.
    assert names == ["(in-process)", "conflictbench-serving", "conflictbench", "lab-policy"], before
    assert all(" files=" in pin for pin in before[1:]) and before[0] == "(in-process)==unknown"

    (package / "processing.py").write_text("SCALE = 0.5\n")  # an edit in an editable install: same version
    after = code_pins(["lab-policy==1.0", "conflictbench==0.2.0", "(in-process)==unknown"])
    changed = sorted(set(before) ^ set(after))
    assert [pin.split(" ")[0] for pin in changed] == ["lab-policy==1.0", "lab-policy==1.0"]  # only the plugin's
    (package / "processing.py").write_text("SCALE = 1.0\n")
    assert code_pins(["lab-policy==1.0", "conflictbench==0.2.0", "(in-process)==unknown"]) == before
    (package / "__pycache__").mkdir()
    (package / "__pycache__" / "processing.cpython-311.pyc").write_bytes(b"compiled")  # a cache is not code
    assert code_pins(["lab-policy==1.0", "conflictbench==0.2.0", "(in-process)==unknown"]) == before


def test_what_changed_is_said_in_words_naming_the_files_a_store_kept(tmp_path):
    before = {"lab_policy/processing.py": "a1", "lab_policy/__init__.py": "b1"}
    after = {"lab_policy/processing.py": "a2", "lab_policy/__init__.py": "b1", "lab_policy/new.py": "c1"}
    old, new = "lab-policy==1.0 files=000000000001", "lab-policy==1.0 files=000000000002"
    keep_manifests(tmp_path, {old: before, new: after})
    keep_manifests(tmp_path, {old: {"overwritten?": "no"}})  # a digest's manifest is written once
    assert code_changes(tmp_path, (old, "conflictbench==0.2.0 files=x"), (new, "conflictbench==0.2.0 files=x")) == [
        "code changed: lab-policy (lab_policy/new.py, lab_policy/processing.py)"
    ]
    assert code_changes(tmp_path, (old,), ("lab-policy==1.1 files=000000000003",)) == ["lab-policy 1.0 -> 1.1"]
    assert code_changes(tmp_path, ("lab-policy==1.0",), (new,)) == [
        "lab-policy: its code is now identified by content (this store's episodes by version)"
    ]
    moved = "lab-policy==1.0 files=000000000004"  # a file deleted, or no longer on the rollout's path
    keep_manifests(tmp_path, {moved: {"lab_policy/processing.py": "a2", "lab_policy/__init__.py": "b1"}})
    assert code_changes(tmp_path, (new,), (moved,)) == ["code changed: lab-policy (1 file no longer counted)"]
    assert code_changes(tmp_path, (old, "(in-process)==x"), (new.replace("2", "9"),)) == [
        "(in-process) removed",
        "code changed: lab-policy",  # no manifest kept for that digest: the files are not named
    ]
