"""The scripted expert and the oracle on real LIBERO episodes (the full 200-episode table is
``benchmarks/scripted_success.py``; these are a sample from every LIBERO suite)."""

from __future__ import annotations

import numpy as np
import pytest
from testing_support import conflict_spec, reference_spec

from conflictbench.core import LIBERO_SUITES
from conflictbench.metrics import pair_metrics
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore
from conflictbench.tasks.suite.file import load_suite

pytestmark = [pytest.mark.sim, pytest.mark.e2e]  # the expert's whole episodes

SAMPLE = {"libero_spatial": 8, "libero_object": 5, "libero_goal": 6, "libero_10": 9}
"""One base task per LIBERO suite: quick ones, and libero_10's mug into the microwave (carried by
its handle under the roof, pushed home, then the door shut), the expert's hardest manoeuvre."""
PAIRED = ("libero_goal", 6)
"""The base task of the scripted/oracle pair tests."""


def _play(plugins, policy, specs, store_dir, workers=2):
    spec = plugins.policy(policy)
    store = EpisodeStore(store_dir)
    result = Runner(plugins, spec, spec.make_config(), store=store, workers=workers, progress=False).run(specs)
    assert result.errors == 0
    records = {r.episode_id: r for r in store.load([(eid, policy) for eid in result.episode_ids])}
    return [records[eid] for eid in result.episode_ids]


@pytest.fixture(scope="module")
def paired(plugins, tmp_path_factory):
    """scripted and oracle, each on one reference and one conflict rollout of the same base task."""
    suite, task_id = PAIRED
    case = next(c for c in load_suite().cases if (c.suite, c.task_id) == PAIRED and c.family == "physical")
    specs = [reference_spec(suite, task_id), conflict_spec(case)]
    store = tmp_path_factory.mktemp("paired")
    return {
        policy: dict(zip(("reference", "conflict"), _play(plugins, policy, specs, store)))
        for policy in ("scripted", "oracle")
    }


def test_scripted_completes_a_base_task_of_every_libero_suite(plugins, tmp_path):
    specs = [reference_spec(suite, task_id) for suite, task_id in SAMPLE.items()]
    records = _play(plugins, "scripted", specs, tmp_path / "store")
    assert {r.suite for r in records} == set(LIBERO_SUITES)
    for record in records:
        assert record.success, f"{record.suite} task {record.task_id} failed after {record.steps} steps"
        assert record.steps < record.max_steps  # the goal, not the budget, ended it
        assert np.abs(record.actions[:, :3]).max() > 0.5  # it really moved


def test_scripted_keeps_executing_the_original_task_under_a_conflict(paired):
    reference, conflict = paired["scripted"]["reference"], paired["scripted"]["conflict"]
    assert conflict.case_id is not None and conflict.instruction != reference.instruction
    assert reference.success and conflict.success
    # it never reads the text: same state, same seed, so the very same rollout
    np.testing.assert_array_equal(conflict.actions, reference.actions)
    np.testing.assert_array_equal(conflict.eef_pos, reference.eef_pos)
    metrics = pair_metrics(reference, conflict)
    assert metrics["tar"] == pytest.approx(1.0) and metrics["ts"] == pytest.approx(1.0)
    assert metrics["ams"] == pytest.approx(0.0)


def test_scripted_rollouts_are_deterministic(plugins, paired, tmp_path):
    again = _play(plugins, "scripted", [reference_spec(*PAIRED)], tmp_path / "again", workers=1)[0]
    first = paired["scripted"]["reference"]
    assert again.steps == first.steps
    np.testing.assert_array_equal(again.actions, first.actions)
    np.testing.assert_array_equal(again.target_pos, first.target_pos)


def test_oracle_matches_scripted_on_references(paired):
    oracle, scripted = paired["oracle"]["reference"], paired["scripted"]["reference"]
    assert oracle.success
    np.testing.assert_array_equal(oracle.raw_actions, scripted.raw_actions)
    np.testing.assert_array_equal(oracle.eef_pos, scripted.eef_pos)


def test_oracle_stays_still_on_conflicts_with_the_ideal_measures(paired):
    reference, conflict = paired["oracle"]["reference"], paired["oracle"]["conflict"]
    assert not conflict.success  # RGSR = 0
    assert conflict.steps == conflict.max_steps
    assert np.all(conflict.actions[:, :6] == 0.0) and np.all(conflict.actions[:, 6] == -1.0)
    drift = np.linalg.norm(conflict.eef_pos - conflict.eef_pos[0], axis=1).max()
    assert drift < 0.005, f"end effector drifted {drift:.4f} m while holding still"
    metrics = pair_metrics(reference, conflict)
    assert metrics["ams"] == 1.0
    assert metrics["tar"] < 0.02  # only the arm's settling under a zero command moves it
