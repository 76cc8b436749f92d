"""Whose failure ended an episode is decided where it was raised: the model's answer, a plugin, our client, the
server, the simulator. Only the model's own answers are scored; the rest are left out and played again."""

from __future__ import annotations

import io

import numpy as np
import pytest

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import (
    ClientError,
    EpisodeRecord,
    InfrastructureError,
    Observation,
    Plugins,
    PolicyError,
)
from conflictbench.sim.deciding import ask_policy, reply_for, reset_error
from conflictbench.sim.messages import Abort, Actions, EpisodeJob
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.slots import Item

SPEC = EpisodeSpec("libero_goal", 3, 0, "p0", "open the drawer")
JOB = EpisodeJob("e1", "libero_goal", 3, "x.bddl", 0, 7, "open the drawer", (), (), 10, 100, False)
ITEM = Item(SPEC, JOB)
OBSERVATION = Observation(
    step=4,
    instruction="open the drawer",
    eef_pos=np.zeros(3),
    eef_quat=np.zeros(4),
    gripper_qpos=np.zeros(2),
    state=np.zeros(8),
)


class Clip:
    def __init__(self, behaviour):
        self.behaviour = behaviour

    @hookimpl
    def conflictbench_postprocess_action(self, action, context):
        return self.behaviour(action)


def decided(raw, post=None) -> Abort | Actions:
    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Clip(post)] if post else [])
    return reply_for(plugins, "noop", ITEM, OBSERVATION, raw)


def test_the_models_answer_is_the_policys_whatever_it_is():
    assert isinstance(decided(np.zeros(7)), Actions)
    for raw in (np.full(7, np.nan), np.zeros(6), PolicyError("the model raised")):
        reply = decided(raw)
        assert isinstance(reply, Abort) and reply.kind == "policy", raw


def test_a_post_processor_that_raises_or_breaks_the_action_is_the_plugins_failure():
    def raises(action):
        raise KeyError("gripper")

    for post in (raises, lambda a: np.full(7, np.inf), lambda a: np.zeros(3)):
        reply = decided(np.zeros(7), post)
        assert isinstance(reply, Abort) and reply.kind == "plugin", reply
    assert "action post-processing raised KeyError" in decided(np.zeros(7), raises).reason


def test_a_servers_error_and_our_clients_error_keep_their_kinds():
    assert decided(InfrastructureError("out of memory")).kind == "server"
    assert decided(ClientError("cannot encode")).kind == "client"
    assert reset_error(InfrastructureError("gone")) == ("infrastructure error: gone", "server")
    assert reset_error(ValueError("bad"))[1] == "policy"


def test_an_in_process_policy_that_raises_is_the_policys_failure():
    class Raises:
        def act(self, observation):
            raise RuntimeError("shape mismatch in the model")

    [out] = ask_policy(Raises(), [OBSERVATION], batched=False)
    assert isinstance(out, PolicyError) and decided(out).kind == "policy"


@pytest.mark.parametrize(
    ("error", "kind", "left_out"),
    [
        (None, None, False),
        ("policy returned NaN", None, False),
        ("simulator error: MuJoCo died", None, True),  # stores from before the column: their text decides
        ("infrastructure error: 500", None, True),
        ("whatever the text", "plugin", True),
        ("whatever the text", "policy", False),
    ],
)
def test_a_records_kind_decides_whether_it_is_left_out(error, kind, left_out):
    record = EpisodeRecord("noop", "libero_goal", 3, 0, "p0", "x", error=error, error_kind=kind)
    assert record.infrastructure_failed is left_out
    if error is not None and kind is None:
        assert record.failure_kind == (
            "simulator" if "simulator" in error else "server" if "500" in error else "policy"
        )


# -- one run through every kind, then the runs after it ------------------------------------------------------------
MARK = 0.123  # the action dim the post-processor below refuses


class Faulty:
    """Each episode fails its own way, the same way every time it is played (by the order it was first seen)."""

    needs_images = False
    max_steps = dict.fromkeys(("libero_spatial", "libero_object", "libero_goal", "libero_10"), 5)
    ways: dict[str, str] = {}
    WAYS = ("fine", "policy", "client", "server", "plugin")

    def __init__(self, cfg=None):
        pass

    def reset(self, instruction):
        pass

    def act(self, observation):
        way = Faulty.ways.setdefault(observation.episode_id, Faulty.WAYS[len(Faulty.ways) % len(Faulty.WAYS)])
        if way == "policy":
            raise RuntimeError("the model's own bug")
        if way == "client":
            raise ClientError("our encode could not pack the image")
        if way == "server":
            raise InfrastructureError("the server ran out of memory")
        return np.array([0, 0, 0, MARK if way == "plugin" else 0, 0, 0, -1.0])


class FaultyPlugin:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("faulty", load=Faulty)

    @hookimpl
    def conflictbench_postprocess_action(self, action, context):
        if action[3] == MARK:
            raise KeyError("a lab's post-processor bug")
        return None


@pytest.mark.sim
@pytest.mark.e2e
def test_every_failure_kind_through_real_runs_only_the_models_is_scored_the_rest_played_again(tmp_path):
    """A real run (LIBERO episodes, workers): the model's failure is stored and scored; a plugin's, our client's and
    the server's are stored apart, counted in the report, played again by the next run, left waiting after two
    identical failures, and played again on run.retry=true."""
    from testing_support import reference_spec

    from conflictbench.report import report_store
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore

    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[FaultyPlugin()])
    spec, store = plugins.policy("faulty"), EpisodeStore(tmp_path / "store")
    episodes = [reference_spec("libero_goal", 0, state) for state in range(5)]
    Faulty.ways = {}

    def run(retry: bool = False):
        return Runner(plugins, spec, spec.make_config({}), store=store, progress=False, retry=retry).run(episodes)

    first = run()
    assert (first.played, first.errors) == (5, 4)
    kinds = {Faulty.ways[r.episode_id]: r.error_kind for r in store.records()}
    assert kinds == {"fine": None, "policy": "policy", "client": "client", "server": "server", "plugin": "plugin"}
    kept = {Faulty.ways[eid] for eid in store.stored_ids()}
    assert kept == {"fine", "policy"}  # scored: the model's failure counts as a failed episode
    assert {Faulty.ways[eid] for eid in store.replay_ids()} == {"client", "server", "plugin"}
    report = io.StringIO()
    report_store(store, plugins, stream=report, figures=False)
    assert "3 episode(s) left out, with their pairs, and played again by the next run: 1 plugin, 1 client, 1 server" \
        in report.getvalue()  # fmt: skip

    assert run().played == 3  # the next run plays the three again; they fail the same way
    third = run()
    assert (third.played, third.failed_twice) == (0, 3)  # left waiting, said in one line
    assert run(retry=True).played == 3
