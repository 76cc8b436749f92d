"""conflictbench.testing.check_pinned_actions: every bit on the processor that recorded the actions, a tolerance of
OTHER_PROCESSOR_ATOL on another (float kernels are picked by processor), and a change of code caught on either."""

from __future__ import annotations

import numpy as np
import pytest

from conflictbench.testing import observations
from conflictbench.testing.observations import OTHER_PROCESSOR_ATOL, RECORD_PINNED_ACTIONS, check_pinned_actions


class Answering:
    """A policy whose action is a fixed function of the observation, moved by ``shift``."""

    def __init__(self, shift: float = 0.0):
        self.shift = shift

    def act(self, observation):
        image = observation.agentview_image.astype(np.float32)
        values = [image.mean() / 255, observation.step / 10, observation.stream, 0, 0, 0, 1]
        return np.array(values, dtype=np.float32) + np.float32(self.shift)


@pytest.fixture
def golden(tmp_path, monkeypatch):
    path = tmp_path / "actions-answering.npz"
    monkeypatch.setenv(RECORD_PINNED_ACTIONS, "1")
    check_pinned_actions(Answering(), path, fingerprint="f1")
    monkeypatch.delenv(RECORD_PINNED_ACTIONS)
    assert str(np.load(path)["processor"]) == observations.processor() != ""
    return path


def test_the_recording_processor_gets_every_bit(golden):
    check_pinned_actions(Answering(), golden, fingerprint="f1")
    with pytest.raises(AssertionError, match="action 0 differs"):
        check_pinned_actions(Answering(shift=1e-7), golden, fingerprint="f1")


def test_another_processor_gets_the_tolerance_and_a_change_of_code_fails_there_too(golden, monkeypatch):
    monkeypatch.setattr(observations, "processor", lambda: "Another CPU")
    check_pinned_actions(Answering(shift=OTHER_PROCESSOR_ATOL / 2), golden, fingerprint="f1")
    with pytest.raises(AssertionError, match=r"is 0\.001 from actions-answering\.npz \(recorded on "):
        check_pinned_actions(Answering(shift=1e-3), golden, fingerprint="f1")


def test_a_file_without_its_processor_is_another_processors(golden):
    saved = dict(np.load(golden))
    del saved["processor"]
    np.savez(golden, **saved)
    check_pinned_actions(Answering(shift=OTHER_PROCESSOR_ATOL / 2), golden, fingerprint="f1")
    with pytest.raises(AssertionError, match="recorded on another processor"):
        check_pinned_actions(Answering(shift=1e-3), golden, fingerprint="f1")


def test_another_fixture_is_named_as_such(golden):
    with pytest.raises(AssertionError, match="the fixture behind actions-answering.npz changed"):
        check_pinned_actions(Answering(), golden, fingerprint="f2")
