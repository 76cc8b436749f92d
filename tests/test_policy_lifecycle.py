"""A policy's start() runs only when a run has something to play, close() always; its identity trait counts."""

from __future__ import annotations

import numpy as np
import pytest
from testing_support import reference_spec

import conflictbench
from conflictbench import hookimpl
from conflictbench.core.plugins import Plugins

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # runs played twice
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")


class LifecyclePolicy:
    """Records what the runner calls; its ``identity`` comes from the class, set by each test."""

    events: list[str] = []
    identity: dict = {}
    needs_images = False
    max_steps = {suite: 3 for suite in SUITES}
    fail_start = False

    def __init__(self, cfg):
        self.events.append("load")

    def start(self):
        self.events.append("start")
        if self.fail_start:
            raise RuntimeError("the model server did not come up")

    def reset(self, instruction):
        pass

    def act(self, observation):
        return np.array([0.0, 0, 0, 0, 0, 0, -1])

    def close(self):
        self.events.append("close")


class Registration:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("lifecycle", load=LifecyclePolicy)


@pytest.fixture
def lifecycle(monkeypatch):
    monkeypatch.setattr(LifecyclePolicy, "events", [])
    monkeypatch.setattr(LifecyclePolicy, "identity", {"checkpoint": "sha256:aaa"})
    return Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[Registration()])


def test_start_runs_once_before_playing_and_never_when_everything_is_stored(play, lifecycle, tmp_path):
    specs = [reference_spec("libero_spatial", 0)]
    result, _ = play("lifecycle", specs, plugin_set=lifecycle, store_dir=tmp_path / "s")
    assert result.played == 1 and LifecyclePolicy.events == ["load", "start", "close"]
    LifecyclePolicy.events.clear()
    result, _ = play("lifecycle", specs, plugin_set=lifecycle, store_dir=tmp_path / "s")
    assert (result.played, result.already_stored) == (0, 1)
    assert LifecyclePolicy.events == ["load", "close"]  # nothing to play: no server started, still closed


def test_a_failing_start_is_one_user_error_and_the_policy_is_still_closed(play, lifecycle, tmp_path, monkeypatch):
    monkeypatch.setattr(LifecyclePolicy, "fail_start", True)
    with pytest.raises(conflictbench.UserError, match="could not start policy 'lifecycle'.*did not come up"):
        play("lifecycle", [reference_spec("libero_spatial", 0)], plugin_set=lifecycle)
    assert LifecyclePolicy.events == ["load", "start", "close"]


def test_the_identity_a_policy_declares_is_part_of_every_episode_identity(play, lifecycle, tmp_path, monkeypatch):
    specs = [reference_spec("libero_spatial", 0)]
    first, _ = play("lifecycle", specs, plugin_set=lifecycle, store_dir=tmp_path / "s")
    monkeypatch.setattr(LifecyclePolicy, "identity", {"checkpoint": "sha256:bbb"})  # other weights, same settings
    second, store = play("lifecycle", specs, plugin_set=lifecycle, store_dir=tmp_path / "s")
    assert (second.played, second.already_stored) == (1, 0)
    assert first.episode_ids != second.episode_ids and len(list(store.records())) == 2
