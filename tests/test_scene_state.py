"""``needs_scene_state``: object poses, regions and scene joints for a learned policy, and nothing about the
task (no goal, no case, no geometry), read from a real LIBERO episode."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from testing_support import reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, Plugins, SceneState
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore

pytestmark = pytest.mark.sim


class Looking:
    """Stands still for 3 steps and keeps what it was shown."""

    needs_images = False
    max_steps = dict.fromkeys(LIBERO_SUITES, 3)

    def __init__(self, privileged: bool):
        self.needs_scene_state = True
        self.needs_privileged = privileged
        self.seen = []

    def reset(self, instruction):
        pass

    def act(self, observation):
        self.seen.append(observation)
        return np.array([0, 0, 0, 0, 0, 0, -1.0])


def observations(tmp_path, privileged: bool) -> list:
    policy = Looking(privileged)

    class Plugin:
        __name__ = "looking"

        @hookimpl
        def conflictbench_register_policies(self, register):
            register("looking", load=lambda cfg: policy)

    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])
    spec = plugins.policy("looking")
    store = EpisodeStore(tmp_path / "store")
    Runner(plugins, spec, spec.make_config(), store=store, workers=1, progress=False).run(
        [reference_spec("libero_goal", 0, 0)]  # "open the middle drawer of the cabinet"
    )
    return policy.seen


def test_a_policy_sees_where_things_are_and_nothing_of_its_task(tmp_path):
    seen = observations(tmp_path, privileged=False)
    assert len(seen) == 3
    scene = seen[0].scene
    assert seen[0].privileged is None
    assert {f.name for f in dataclasses.fields(SceneState)} == {"body_poses", "site_positions", "joint_positions"}
    assert scene.body_poses and all(pose.shape == (7,) for pose in scene.body_poses.values())
    assert any("drawer" in name or "cabinet" in name for name in scene.joint_positions)  # the drawer's joints
    assert any(name.endswith("_region") for name in scene.site_positions)
    assert all(np.all(np.isfinite(p)) for p in scene.site_positions.values())


@pytest.mark.e2e
def test_the_scene_state_agrees_with_the_privileged_state(tmp_path):
    first = observations(tmp_path, privileged=True)[0]
    scene, truth = first.scene, first.privileged
    assert set(scene.body_poses) == set(truth.body_poses)
    for name, pose in scene.body_poses.items():
        np.testing.assert_array_equal(pose, truth.body_poses[name])
    assert scene.joint_positions == dict(truth.joint_positions)
    assert set(scene.site_positions) == set(truth.site_positions)
