"""A simulator worker killed mid-episode: the worker restarts, that episode is played again (a second loss
stores it as an infrastructure failure, for the next run to play) and the run goes on; an answer to the dead
worker's query never reaches the next episode."""

from __future__ import annotations

import time

import numpy as np
import pytest
from testing_support import reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import INFRASTRUCTURE_ERROR_PREFIX, LIBERO_SUITES, Plugins
from conflictbench.sim.runner import Runner, RunResult
from conflictbench.store import EpisodeStore

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # runs whose workers are killed


def specs():  # built when a test runs: collecting this module must not need the simulator
    return [reference_spec("libero_object", 4, 0), reference_spec("libero_object", 4, 1)]


class Still:
    """Stands still; with ``concurrent_requests`` it answers slowly from threads, like a served policy,
    and marks each action with the step it answers (dim 3) and whether it is the first episode's (dim 4)."""

    needs_images = False
    max_steps = dict.fromkeys(LIBERO_SUITES, 30)

    def __init__(self, concurrent: bool, on_query=lambda calls: None):
        self.calls, self.first_episode, self.on_query = 0, None, on_query
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
        self.on_query(self.calls)
        self.first_episode = self.first_episode or observation.episode_id
        time.sleep(delay)
        action = np.array([0, 0, 0, 0.001 * observation.step, 0, 0, -1.0])
        action[4] = 0.1 if observation.episode_id == self.first_episode else 0.2
        return action


def run_killing_the_worker(tmp_path, concurrent: bool, at_calls: list[int]) -> tuple[EpisodeStore, RunResult]:
    """Kill the worker when the policy is asked its ``at_calls[0]``-th query, again at its ``at_calls[1]``-th ...
    (by the policy itself, so the kill lands on that query however busy the machine: a thread polling the count
    every 20 ms could land steps late, and a second kill in the wrong episode)."""

    def kill_at(calls: int) -> None:
        if calls in at_calls:
            runner._pool.slots[0].process.kill()

    class Plugin:
        __name__ = "still"

        @hookimpl
        def conflictbench_register_policies(self, register):
            register("still", load=lambda cfg: Still(concurrent, kill_at))

    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])
    spec = plugins.policy("still")
    store = EpisodeStore(tmp_path / "store")
    runner = Runner(plugins, spec, spec.make_config(), store=store, workers=1, progress=False)

    result = runner.run(specs())
    return store, result


def test_a_killed_workers_episode_is_played_again_and_the_run_goes_on(tmp_path):
    store, result = run_killing_the_worker(tmp_path, concurrent=False, at_calls=[5])
    assert (result.played, result.replayed_after_loss, result.errors) == (2, 1, 0)
    first, second = sorted(store.records(), key=lambda r: r.init_state)
    assert first.error is None and first.steps == 30  # played whole the second time
    np.testing.assert_allclose(first.raw_actions[:, 3], 0.001 * np.arange(30))
    assert second.error is None and second.steps == 30


def test_an_episode_lost_twice_is_an_infrastructure_failure_the_next_run_plays_again(tmp_path):
    # First episode killed at its 5th query, the second played (30), the first again killed at its 5th.
    store, result = run_killing_the_worker(tmp_path, concurrent=False, at_calls=[5, 40])
    assert (result.played, result.replayed_after_loss, result.errors) == (2, 1, 1)
    first, second = sorted(store.records(), key=lambda r: r.init_state)
    assert first.error.startswith(INFRASTRUCTURE_ERROR_PREFIX) and "worker process died" in first.error
    assert second.error is None and second.steps == 30
    assert store.stored_ids() == {second.episode_id}  # not the lost one: the next run plays it again


def test_an_answer_for_a_dead_workers_query_never_reaches_the_next_episode(tmp_path):
    # The worker dies while its 5th query is being answered (2 s); the slot then plays the next episode,
    # then the first one again.
    store, result = run_killing_the_worker(tmp_path, concurrent=True, at_calls=[5])
    first, second = sorted(store.records(), key=lambda r: r.init_state)
    assert first.error is None and second.error is None and first.steps == second.steps == 30
    np.testing.assert_array_equal(second.raw_actions[:, 4], 0.2)  # only answers to its own queries ...
    np.testing.assert_allclose(second.raw_actions[:, 3], 0.001 * np.arange(30))  # ... each for its own step
    np.testing.assert_array_equal(first.raw_actions[:, 4], 0.1)
    np.testing.assert_allclose(first.raw_actions[:, 3], 0.001 * np.arange(30))
