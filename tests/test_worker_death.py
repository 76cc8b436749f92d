"""A simulator worker killed mid-episode: that episode is stored as a simulator failure, the worker
restarts and the run goes on; an answer to the dead worker's query never reaches the next episode."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from testing_support import reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, SIMULATOR_ERROR_PREFIX, Plugins
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore

pytestmark = pytest.mark.sim


def specs():  # built when a test runs: collecting this module must not need the simulator
    return [reference_spec("libero_object", 4, 0), reference_spec("libero_object", 4, 1)]


class Still:
    """Stands still; with ``concurrent_requests`` it answers slowly from threads, like a served policy,
    and marks each action with the step it answers (dim 3) and whether it is the first episode's (dim 4)."""

    needs_images = False
    max_steps = dict.fromkeys(LIBERO_SUITES, 30)

    def __init__(self, concurrent: bool):
        self.calls, self.first_episode = 0, None
        if concurrent:
            self.concurrent_requests = True
            self.act_batch = self._act_batch

    def reset(self, instruction):
        pass

    def act(self, observation):
        return self._answer(observation, delay=0.0)

    def _act_batch(self, observations):
        return [self._answer(obs, delay=2.0 if self.calls == 4 else 0.1) for obs in observations]  # 5th: slow

    def _answer(self, observation, delay: float):
        self.calls += 1
        self.first_episode = self.first_episode or observation.episode_id
        time.sleep(delay)
        action = np.array([0, 0, 0, 0.001 * observation.step, 0, 0, -1.0])
        action[4] = 0.1 if observation.episode_id == self.first_episode else 0.2
        return action


def run_killing_the_worker(tmp_path, concurrent: bool, when) -> EpisodeStore:
    class Plugin:
        __name__ = "still"

        @hookimpl
        def conflictbench_register_policies(self, register):
            register("still", load=lambda cfg: Still(concurrent))

    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])
    spec = plugins.policy("still")
    store = EpisodeStore(tmp_path / "store")
    runner = Runner(plugins, spec, spec.make_config(), store=store, workers=1, progress=False)

    def kill() -> None:
        deadline = time.time() + 120
        while time.time() < deadline and not (runner._policy is not None and when(runner._policy)):
            time.sleep(0.02)
        runner._pool.slots[0].process.kill()

    threading.Thread(target=kill, daemon=True).start()
    result = runner.run(specs())
    assert result.played == 2
    return store


def test_a_killed_worker_is_a_simulator_failure_and_the_run_goes_on(tmp_path):
    store = run_killing_the_worker(tmp_path, concurrent=False, when=lambda policy: policy.calls >= 5)
    first, second = sorted(store.records(), key=lambda r: r.init_state)
    assert first.error.startswith(SIMULATOR_ERROR_PREFIX) and "worker process died" in first.error
    assert second.error is None and second.steps == 30


def test_an_answer_for_a_dead_workers_query_never_reaches_the_next_episode(tmp_path):
    # The worker dies while its 5th query is being answered (2 s); the slot then plays the next episode.
    store = run_killing_the_worker(tmp_path, concurrent=True, when=lambda policy: policy.calls >= 5)
    first, second = sorted(store.records(), key=lambda r: r.init_state)
    assert first.error.startswith(SIMULATOR_ERROR_PREFIX)
    assert second.error is None and second.steps == 30
    np.testing.assert_array_equal(second.raw_actions[:, 4], 0.2)  # only answers to its own queries ...
    np.testing.assert_allclose(second.raw_actions[:, 3], 0.001 * np.arange(30))  # ... each for its own step
