"""Sampling randomness derived from the episode and step, and per-episode policy state (no simulator)."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np

import conflictbench
from conflictbench.core import Observation, PerEpisode, rng_for, sampling_seed
from conflictbench.policies import RandomConfig, RandomPolicy


def obs(episode_id: str = "e1", step: int = 0, stream: int = 0, **kw) -> Observation:
    return Observation(
        step=step,
        instruction=kw.pop("instruction", "pick up the bowl"),
        eef_pos=np.zeros(3),
        eef_quat=np.array([0.0, 0.0, 0.0, 1.0]),
        gripper_qpos=np.zeros(2),
        state=np.zeros(8),
        stream=stream,
        episode_id=episode_id,
        **kw,
    )


def test_the_sampling_api_is_public():
    assert conflictbench.rng_for is rng_for and conflictbench.sampling_seed is sampling_seed
    assert conflictbench.PerEpisode is PerEpisode


def test_the_seed_depends_on_episode_and_step_only():
    base = sampling_seed(obs())
    assert sampling_seed(obs(stream=1, instruction="other text", joint_positions=np.ones(7))) == base
    assert sampling_seed(obs(step=1)) != base and sampling_seed(obs(episode_id="e2")) != base
    assert 0 <= base < 2**64


def test_a_sampling_key_seeds_in_place_of_the_episode_id():
    """The runner hands the episode's identity by settings and versions: a code edit leaves the draws alone."""
    keyed = sampling_seed(obs(episode_id="by-content-1", sampling_key="by-versions"))
    assert sampling_seed(obs(episode_id="by-content-2", sampling_key="by-versions")) == keyed
    assert keyed == sampling_seed(obs(episode_id="by-versions"))
    assert sampling_seed(obs(episode_id="by-content-1", sampling_key="other")) != keyed


def test_the_seed_is_the_same_in_every_process():
    # hash() is salted per process; the seed must not be
    code = (
        "import numpy as np; from conflictbench.core import Observation, sampling_seed; "
        "print(sampling_seed(Observation(step=5, instruction='', eef_pos=np.zeros(3), eef_quat=np.zeros(4), "
        "gripper_qpos=np.zeros(2), state=np.zeros(8), episode_id='abc')))"
    )
    seeds = {
        subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            check=True,
            env={**os.environ, "PYTHONHASHSEED": salt},
        ).stdout.strip()
        for salt in ("1", "2")
    }
    assert seeds == {str(sampling_seed(obs(episode_id="abc", step=5)))}


def test_rng_for_is_reproducible_and_mixes_in_the_model_seed():
    draw = lambda o, *keys: rng_for(o, *keys).uniform(size=4)  # noqa: E731
    np.testing.assert_array_equal(draw(obs(), 3), draw(obs(), 3))
    assert not np.array_equal(draw(obs(), 3), draw(obs(), 4))
    assert not np.array_equal(draw(obs(), 3), draw(obs(step=1), 3))
    draw(obs(), -1)  # negative seeds are accepted


def test_random_policy_actions_do_not_depend_on_call_order():
    policy = RandomPolicy(RandomConfig(seed=5))
    queries = [obs(episode_id=e, step=s, stream=i) for s in range(3) for i, e in enumerate(("a", "b"))]
    interleaved = {(o.episode_id, o.step): policy.act(o) for o in queries}
    fresh = RandomPolicy(RandomConfig(seed=5))
    one_by_one = {(o.episode_id, o.step): fresh.act(o) for o in sorted(queries, key=lambda o: o.episode_id)}
    batched = dict(zip([(o.episode_id, o.step) for o in queries], fresh.act_batch(queries)))
    for key, action in interleaved.items():
        np.testing.assert_array_equal(action, one_by_one[key])
        np.testing.assert_array_equal(action, batched[key])
    assert not np.array_equal(interleaved[("a", 0)], interleaved[("b", 0)])
    other_seed = RandomPolicy(RandomConfig(seed=6)).act(queries[0])
    assert not np.array_equal(other_seed, interleaved[("a", 0)])


def test_per_episode_state_is_kept_per_stream_and_renewed_with_each_episode():
    made: list[list] = []

    def fresh() -> list:
        made.append([])
        return made[-1]

    states = PerEpisode(fresh)
    states(obs("a", 0, stream=0)).append("a0")
    states(obs("b", 0, stream=1)).append("b0")
    states(obs("a", 4, stream=0)).append("a4")  # interleaved with stream 1: still episode a's state
    assert made == [["a0", "a4"], ["b0"]]
    assert states(obs("c", 0, stream=0)) == [] and len(made) == 3  # stream 0 starts episode c
    states(obs("c", 3, stream=0)).append("c3")
    assert made[2] == ["c3"]
    # the same (empty) identity twice, as in observations built by hand: step 0 starts afresh
    anonymous = dataclasses.replace(obs("", 0, stream=0))
    assert states(anonymous) == [] and len(made) == 4
