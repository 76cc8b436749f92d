"""A simulator failure is the policy's doing when its actions bring a fresh simulator to the same failure.

The env is a stand-in for LIBERO's (the boundary: its failures cannot be provoked on demand); playing real
episodes through the same worker is test_sim_engine.py's, and MuJoCo's warnings are read off a real simulator.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from conflictbench.sim.messages import EpisodeJob
from conflictbench.sim.worker import EpisodePlayer

pytestmark = pytest.mark.sim  # the initial states come from LIBERO's files

JOB = EpisodeJob("e1", "libero_goal", 3, "unused.bddl", 0, 7, "open the drawer", (), (), 2, 50, False)


class StandInEnv:
    """Fails on its ``fail_at``-th step with a large action, or, where ``flaky``, only in the first env built."""

    built = 0

    def __init__(self, fail_at: int, flaky: bool):
        StandInEnv.built += 1
        self.fail_at, self.flaky, self.first = fail_at, flaky, StandInEnv.built == 1
        self.steps = 0

    def seed(self, seed):
        pass

    def reset(self):
        self.steps = 0

    def set_init_state(self, state):
        return {}

    def step(self, action):
        self.steps += 1
        if self.steps >= self.fail_at and abs(action[0]) > 0.5 and (self.first or not self.flaky):
            raise ValueError("mj_step: simulation diverged at step 12")
        return {}, 0.0, False, {}

    def close(self):
        pass


def player(fail_at: int, flaky: bool) -> EpisodePlayer:
    StandInEnv.built = 0
    played = EpisodePlayer(types.SimpleNamespace(needs_images=False))
    played._libero_env = types.SimpleNamespace(make_env=lambda path, settings: StandInEnv(fail_at, flaky))
    played._env_for(JOB)  # the env the episode failed in; the worker closes it before replaying
    played.close()
    return played


def test_a_failure_the_actions_bring_about_again_is_the_policys_and_a_flaky_one_is_not():
    actions = [np.zeros(7), np.zeros(7), np.array([0.9, 0, 0, 0, 0, 0, -1.0])]
    failure = "ValueError: mj_step: simulation diverged at step 12"
    assert player(fail_at=3, flaky=False).fails_again(JOB, actions, failure)
    assert not player(fail_at=3, flaky=True).fails_again(JOB, actions, failure)
    assert not player(fail_at=3, flaky=False).fails_again(JOB, actions, "ValueError: another message")
    assert not player(fail_at=3, flaky=False).fails_again(JOB, actions[:2], failure)  # the actions alone are fine


def test_mujocos_warnings_are_read_off_the_episodes_simulator(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to MUJOCO_LOG.TXT in the working directory
    from conflictbench.sim.libero_env import EnvSettings, configure_process, make_env
    from conflictbench.sim.worker import simulator_warnings
    from conflictbench.tasks.libero.base_tasks import base_task

    configure_process(EnvSettings(needs_images=False))
    env = make_env(base_task("libero_goal", 3).bddl_path, EnvSettings(needs_images=False))
    try:
        env.seed(0)
        env.reset()
        env.step(np.zeros(7))
        assert simulator_warnings(env) == ()
        env.sim.data.qvel[:] = 1e200  # what a diverging simulation looks like: MuJoCo warns and resets it
        env.step(np.zeros(7))
        assert simulator_warnings(env) == ("mjWARN_BADQVEL x1",)
        env.reset()  # a new simulator: a new count
        assert simulator_warnings(env) == ()
    finally:
        env.close()
