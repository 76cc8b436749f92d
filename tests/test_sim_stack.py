"""The stack below the policy, probed in a worker before a run plans: part of every episode's identity and record,
the renderer where images count; a worker on another stack than the probe's stops the run."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from testing_support import reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, Plugins, PolicyTraits, SimulatorUnavailable
from conflictbench.sim import stack as stack_module
from conflictbench.sim.libero_env import EnvSettings, simulator_versions
from conflictbench.sim.plan import config_hash
from conflictbench.sim.stack import probe_in_worker

pytestmark = pytest.mark.sim


@dataclass
class StillConfig:
    images: bool = False


class Still:
    max_steps = dict.fromkeys(LIBERO_SUITES, 3)

    def __init__(self, cfg: StillConfig):
        self.needs_images = cfg.images

    def reset(self, instruction):
        pass

    def act(self, observation):
        return np.array([0, 0, 0, 0, 0, 0, -1.0])


class StillPlugin:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("still", load=Still, config=StillConfig)


def test_the_probe_says_the_simulator_and_where_images_count_the_renderer_and_image_libraries():
    state_only = probe_in_worker(EnvSettings(needs_images=False))
    assert state_only == simulator_versions()  # what the store's version columns hold, nothing else
    cameras = probe_in_worker(EnvSettings(needs_images=True))
    assert {k: cameras[k] for k in state_only} == state_only
    assert cameras["gl_backend"] == "egl" and cameras["gl_renderer"] and cameras["gl_vendor"]
    assert cameras.get("pillow")  # the sim extra's image library
    traits = PolicyTraits(Still(StillConfig(images=True)))
    other_gpu = {**cameras, "gl_vendor": "NVIDIA Corporation", "gl_renderer": "NVIDIA H200/PCIe/SSE2"}
    assert config_hash("still", None, traits, (), cameras) != config_hash("still", None, traits, (), other_gpu)


def test_records_carry_the_renderer_of_an_image_policy_and_a_worker_on_another_stack_stops_the_run(
    play, tmp_path, monkeypatch
):
    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[StillPlugin()])
    _, store = play("still", [reference_spec("libero_goal", 0)], settings={}, plugin_set=plugins)
    assert store.records()[0].sim_stack == ()  # state-only: the simulator's versions say it all
    _, store = play("still", [reference_spec("libero_goal", 0)], settings={"images": True}, plugin_set=plugins,
                    store_dir=tmp_path / "cameras")  # fmt: skip
    (record,) = store.records()
    stack = dict(pin.split("=", 1) for pin in record.sim_stack)
    assert stack["gl_backend"] == "egl" and stack["gl_renderer"]

    probed = stack_module.probe_in_worker

    def elsewhere(settings):  # what the probe says on a machine whose workers then render with another GPU
        return {**probed(settings), "gl_renderer": "NVIDIA H200/PCIe/SSE2"}

    monkeypatch.setattr(stack_module, "probe_in_worker", elsewhere)
    with pytest.raises(SimulatorUnavailable, match=r"gl_renderer: NVIDIA H200/PCIe/SSE2 vs "):
        play("still", [reference_spec("libero_goal", 0, 1)], settings={"images": True}, plugin_set=plugins,
             store_dir=tmp_path / "mixed")  # fmt: skip
