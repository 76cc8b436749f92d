"""The code in an episode's identity is the files' content: an edit makes stored episodes stale, a version does not
hide one, and only the code on a rollout's path counts."""

from __future__ import annotations

import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import conflictbench
from conflictbench.sim.code_identity import NOT_ROLLOUT, ROLLOUT_PACKAGES, code_pins, distribution_files
from conflictbench.sim.identity_change import code_changes, keep_manifests


def _covered(module: str) -> bool:
    return module.startswith(tuple(p + "." for p in ROLLOUT_PACKAGES)) or module in ROLLOUT_PACKAGES


def test_every_module_of_conflictbench_is_said_to_be_on_a_rollouts_path_or_not():
    modules = [m.name for m in pkgutil.walk_packages(conflictbench.__path__, "conflictbench.")]
    assert "conflictbench.sim.worker" in modules and "conflictbench.report.tables" in modules
    unlisted = [
        m for m in modules if not _covered(m) and ".".join(m.split(".")[:2]) not in NOT_ROLLOUT and m not in NOT_ROLLOUT
    ]
    assert unlisted == [], f"say whether these can change an episode (sim/code_identity.py): {unlisted}"
    assert not set(NOT_ROLLOUT) & set(ROLLOUT_PACKAGES)


@pytest.mark.sim
def test_a_worker_imports_nothing_of_conflictbench_off_the_rollout_packages():
    """What a simulator worker imports, as a run starts it (sim/worker.py, then the simulator)."""
    probe = (
        "import sys\n"
        "from conflictbench.sim import worker\n"
        "from conflictbench.sim.libero_env import EnvSettings, configure_process\n"
        "configure_process(EnvSettings(needs_images=False))\n"
        "import libero.libero.envs\n"
        "from conflictbench.sim import capture, compiled_models\n"
        "print(' '.join(m for m in sys.modules if m.startswith('conflictbench')))"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    imported = done.stdout.split()
    assert "conflictbench.sim.worker" in imported and "conflictbench.tasks.libero.base_tasks" in imported
    assert [m for m in imported if not _covered(m)] == ["conflictbench"]  # the package itself, a parent


def test_conflictbench_counts_its_rollout_packages_and_not_the_report_or_the_viewer():
    names = {name for name, _ in distribution_files("conflictbench")}
    assert {"conflictbench/sim/worker.py", "conflictbench/policies/subject/subject.npz"} <= names
    assert "conflictbench/hosting/client.py" in names and "conflictbench/core/prompts.py" in names
    assert not [n for n in names if n.split("/")[1] in ("report", "view", "store", "cli", "metrics")]
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]


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
    assert code_changes(tmp_path, (old, "(in-process)==x"), (new.replace("2", "9"),)) == [
        "(in-process) removed",
        "code changed: lab-policy",  # no manifest kept for that digest: the files are not named
    ]
