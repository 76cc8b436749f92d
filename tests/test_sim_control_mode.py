"""A policy's ``control_mode`` on real LIBERO episodes, and the raw robot state every observation carries (#44)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pytest
from testing_support import reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, Plugins, PolicyTraits
from conflictbench.sim.replay import ReplayJob, replay_all
from conflictbench.sim.worker import as_stepped

pytestmark = pytest.mark.sim
SHORT = {suite: 12 for suite in LIBERO_SUITES}
LIFT = 0.05  # metres above the first observed end-effector position


@dataclass
class HoldConfig:
    control_mode: str = "relative"


class HoldAbove:
    """Commands, at every step, the pose LIFT above where the end-effector first was, with its first orientation:
    a target pose under absolute control, a large delta under relative control."""

    seen: list = []

    def __init__(self, cfg: HoldConfig):
        self.control_mode = cfg.control_mode
        self.max_steps = SHORT
        self.needs_images = False
        self._action = None

    def reset(self, instruction: str) -> None:
        self._action = None

    def act(self, obs):
        HoldAbove.seen.append(obs)
        if self._action is None:
            from robosuite.utils.transform_utils import mat2quat, quat2axisangle

            # The controller's own frame (eef_mat), which an absolute target orientation is compared with.
            orientation = quat2axisangle(mat2quat(obs.eef_mat))
            self._action = np.concatenate([obs.eef_pos + [0, 0, LIFT], orientation, [-1.0]])
        return self._action


class Plugin:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("hold-above", load=HoldAbove, config=HoldConfig)


@pytest.fixture(scope="module")
def hold_plugins():
    return Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])


def test_absolute_control_reaches_the_commanded_pose_and_relative_reads_it_as_a_delta(play, hold_plugins, tmp_path):
    paths, records = {}, {}
    for mode in ("absolute", "relative"):
        HoldAbove.seen.clear()
        result, store = play(
            "hold-above",
            [reference_spec("libero_goal", 0)],
            settings={"control_mode": mode},
            plugin_set=hold_plugins,
            store_dir=tmp_path / mode,
        )
        assert result.played == 1 and result.errors == 0
        (record,) = store.records()
        paths[mode], records[mode] = record.eef_pos, record
        assert record.control_mode == mode  # stored: what a replay sets again
        first = HoldAbove.seen[0]
        # Every observation carries the raw robot state LeRobot's LIBERO env reports.
        assert first.joint_velocities.shape == (7,) and first.gripper_qvel.shape == (2,)
        mat = first.eef_mat
        assert mat.shape == (3, 3) and np.allclose(mat @ mat.T, np.eye(3), atol=1e-9)
        from robosuite.utils.transform_utils import quat2mat

        # The controller's matrix (the grip site's frame), not one derived from robosuite's observed quaternion (the
        # hand's): a quarter turn about z apart, up to the sub-step between their samples.
        quarter_turn = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        assert np.allclose(mat, quat2mat(first.eef_quat.copy()) @ quarter_turn, atol=1e-3)
        assert np.linalg.det(mat) == pytest.approx(1.0, abs=1e-9)
    # The warm-up's no-ops run under delta control in both modes: the mode is set after it.
    assert np.array_equal(paths["absolute"][0], paths["relative"][0])
    start, absolute, relative = paths["absolute"][0], paths["absolute"][-1], paths["relative"][-1]
    # Absolute: the arm rises towards the target and stays over its start.
    assert absolute[2] - start[2] > 0.01 and np.linalg.norm(absolute[:2] - start[:2]) < 0.01
    # Relative: the same rows are clipped deltas of about a metre in x and z: the arm runs far from its start.
    assert np.linalg.norm(relative - start) > 3 * np.linalg.norm(absolute - start)
    # A replay (a video's) retraces the absolute episode exactly when it sets the stored mode again.
    record = records["absolute"]
    as_played = ReplayJob.of(record, NullSink())
    as_relative = replace(as_played, control_mode="relative")
    (played,) = replay_all([as_played], workers=1)
    assert played.error is None and played.deviation_m == 0.0
    (wrong,) = replay_all([as_relative], workers=1)
    assert wrong.error is None and wrong.deviation_m > 0.05


def test_absolute_control_steps_float32_rows_and_relative_leaves_them_as_they_are():
    row = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, -1.0]) / 3
    assert as_stepped(row, "absolute").dtype == np.float32
    assert np.array_equal(as_stepped(row, "absolute"), row.astype(np.float32))
    assert as_stepped(row, "relative") is row


class NullSink:
    """Keeps no frame."""

    def open(self):
        pass

    def add(self, frame):
        pass

    def close(self):
        return 0

    def abort(self):
        pass


def test_only_a_control_mode_other_than_the_default_enters_the_identity():
    class Relative:
        pass

    class Absolute:
        control_mode = "absolute"

    assert "control_mode" not in PolicyTraits(Relative()).as_dict()
    assert PolicyTraits(Absolute()).as_dict()["control_mode"] == "absolute"
    with pytest.raises(ValueError, match="control_mode must be one of relative, absolute"):
        PolicyTraits(type("Odd", (), {"control_mode": "velocity"})())
