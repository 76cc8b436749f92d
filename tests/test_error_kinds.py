"""Whose failure ended an episode is decided where it was raised: the model's answer, a plugin, our client, the
server, the simulator. Only the model's own answers are scored; the rest are left out and played again."""

from __future__ import annotations

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
from conflictbench.sim.pool import Item

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
