"""An episode's identity covers the code that can change it: upgrading a plugin, or installing one
that post-processes actions, plays the episodes again instead of reusing the old ones."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from testing_support import DEMO_PLUGIN, pip_install_into, reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import Plugins
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # real runs with two versions of a plugin


def install_demo(version: str, target: Path) -> Path:
    """The demo plugin as a real installed distribution of the given version."""
    source = target.parent / f"src-{version}"
    shutil.copytree(DEMO_PLUGIN, source)
    project = source / "pyproject.toml"
    project.write_text(project.read_text().replace('version = "0.3.1"', f'version = "{version}"'))
    pip_install_into(target, source)
    return target


class Halve:
    """A cross-cutting post-processor installed later (a lab that scales every action)."""

    __name__ = "halve"

    @hookimpl
    def conflictbench_postprocess_action(self, action, context):
        out = action.copy()
        out[:6] *= 0.5
        return out


def play(site: Path, store: EpisodeStore, monkeypatch, *extra) -> int:
    with monkeypatch.context() as m:
        m.syspath_prepend(str(site))
        plugins = Plugins(BUILTIN_PLUGINS, extra=extra)
        spec = plugins.policy("demo-wave")
        settings = spec.make_config({"noise": 0.1})  # it samples: its draws are seeded per episode and step
        runner = Runner(plugins, spec, settings, store=store, workers=1, progress=False)
        return runner.run([reference_spec("libero_spatial", 0, 0)]).played


def halves(record) -> bool:
    """Whether the episode was played with the in-process post-processor ``Halve`` installed."""
    return any(pin.startswith("(in-process)==") for pin in record.code_versions)


def test_a_plugin_upgrade_or_a_new_post_processor_plays_the_episodes_again(tmp_path, monkeypatch, capfd):
    old = install_demo("0.3.1", tmp_path / "site-old")
    new = install_demo("0.3.2", tmp_path / "site-new")
    store = EpisodeStore(tmp_path / "store")

    def why() -> str:
        said = [line for line in capfd.readouterr().err.splitlines() if "under another identity" in line]
        return said[0].split("are not reused: ")[1] if said else ""

    assert play(old, store, monkeypatch) == 1
    assert play(old, store, monkeypatch) == 0  # same code: reused
    assert why() == ""
    assert play(new, store, monkeypatch) == 1  # the policy's plugin upgraded
    assert why() == "conflictbench-demo 0.3.1 -> 0.3.2"
    assert play(new, store, monkeypatch, Halve()) == 1  # a post-processor installed
    assert why() == "(in-process) added"
    assert play(new, store, monkeypatch, Halve()) == 0
    (halved,) = [r for r in store.records() if halves(r)]
    module = new / "conflictbench_demo" / "__init__.py"
    module.write_text(module.read_text() + "\n# one line edited, the version unchanged\n")
    assert play(new, store, monkeypatch, Halve()) == 1  # other code: played again, and the file named
    assert why() == "code changed: conflictbench-demo (conflictbench_demo/__init__.py)"
    assert play(new, store, monkeypatch, Halve()) == 0
    records = store.records()
    assert len(records) == 4 and len({r.config_hash for r in records}) == 4
    # The edit changed no action: the episode played again drew the noise it drew before (sampling is seeded by
    # the identity by settings and versions), so its actions are the same; another version draws other noise.
    (edited,) = [r for r in records if halves(r) and r.episode_id != halved.episode_id]
    np.testing.assert_array_equal(edited.actions, halved.actions)
    old_version, new_version = sorted((r for r in records if not halves(r)), key=lambda r: r.plugin_version)
    assert np.abs(old_version.raw_actions - new_version.raw_actions).max() > 0.01
    assert {r.plugin_version for r in records} == {"0.3.1", "0.3.2"}
    demo_pins = {pin for r in records for pin in r.code_versions if pin.startswith("conflictbench-demo==")}
    assert {pin.split(" files=")[0] for pin in demo_pins} == {"conflictbench-demo==0.3.1", "conflictbench-demo==0.3.2"}
    assert len(demo_pins) == 3  # 0.3.1, and 0.3.2 before and after the edit
    assert sum("(in-process)==" in pin for r in records for pin in r.code_versions) == 2  # the post-processor
    # The three older identities are superseded by the last: prune removes them, and the store still holds the
    # episode today's code plays.
    from conflictbench.store.prune import superseded

    assert {s.episode_id for s in superseded(store)} == {r.episode_id for r in records} - {edited.episode_id}
    for item in superseded(store):
        item.path.unlink()
    assert play(new, store, monkeypatch, Halve()) == 0
