"""``conflictbench doctor model=NAME``'s lines for the built-in policies and for a user's mistakes (no server: the
served models' lines are tested against real servers in their plugins, e.g. plugins/pi0/tests/test_pi0_doctor.py)."""

from __future__ import annotations

import pytest

import conflictbench
from conflictbench.core import UserError, hookimpl
from conflictbench.doctor.models import model_checks


@pytest.fixture(scope="module")
def plugins():
    return conflictbench.plugins(entry_points=False)


def test_an_in_process_policy_answers_one_observation_with_a_seven_vector(plugins):
    checks = model_checks(["model=random", "model.seed=3"], plugins)
    assert [c.name for c in checks] == ["plugin", "load", "request"] and all(c.passed for c in checks)
    assert "in process: an action of shape (7,)" in checks[-1].text


def test_a_policy_reading_the_simulator_says_it_answers_only_in_a_run(plugins):
    for name in ("scripted", "subject"):
        request = model_checks([f"model={name}"], plugins)[-1]
        assert request.passed and f"conflictbench model={name}" in request.text


class Broken:
    """A plugin whose policy loads and then fails on every request (weights gone bad)."""

    class Policy:
        def reset(self, instruction):
            pass

        def act(self, observation):
            raise RuntimeError("weights are NaN")

    @staticmethod
    @hookimpl
    def conflictbench_register_policies(register):
        register("broken", load=lambda cfg: Broken.Policy())


def test_a_policy_that_fails_on_a_request_is_a_failed_request_line():
    checks = model_checks(["model=broken"], conflictbench.plugins(entry_points=False, extra=[Broken]))
    assert checks[-1].name == "request" and not checks[-1].passed
    assert "RuntimeError: weights are NaN" in checks[-1].text


@pytest.mark.parametrize(
    "argv, words",
    [
        (["model=nope"], "unknown model"),
        (["model=noop", "model=random"], "one model at a time"),
        (["model=noop,random"], "one model at a time"),
        (["suite=physical", "model=noop"], "model=NAME"),
        (["model=random", "model.sed=3"], "no setting 'sed'"),
        ([], "one model at a time"),
    ],
)
def test_a_mistake_is_one_user_error(plugins, argv, words):
    with pytest.raises(UserError, match=words):
        model_checks(argv, plugins)
