"""Reports streamed from a real Parquet store equal reports from records held in memory."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd

from conflictbench.core import EpisodeRecord
from conflictbench.report import report_records, report_store
from conflictbench.store import EpisodeStore


def episode(rng, policy, case, state, success, prompt="p0", family="spatial", level="L1"):
    h = int(rng.integers(3, 30))
    return EpisodeRecord(
        policy=policy,
        suite="libero_goal",
        task_id=state % 3,
        init_state=state,
        prompt=prompt,
        instruction=f"do {case}",
        case_id=case,
        family=family if case else None,
        level=level if case else None,
        success=success,
        steps=h,
        episode_id=f"{policy}-{case}-{state}-{prompt}",
        eef_pos=rng.normal(size=(h + 1, 3)) * 0.1,
        target_pos=rng.normal(size=(h + 1, 2, 3)),
        target_names=("a", "b"),
        actions=rng.normal(size=(h, 7)),
        raw_actions=rng.normal(size=(h, 7)),
        config_hash="h",
    )


def test_streamed_report_matches_the_in_memory_one(tmp_path):
    import conflictbench

    rng = np.random.default_rng(4)
    records = []
    for policy in ("alpha", "beta"):
        for state in range(4):
            for prompt in ("p0", "p1"):
                records.append(episode(rng, policy, None, state, bool(rng.integers(2)), prompt))
                for case, family in (("c1", "spatial"), ("c2", "physical"), ("c3", "grounding")):
                    records.append(episode(rng, policy, case, state, bool(rng.integers(2)), prompt, family))
    records.append(episode(rng, "alpha", "c4", 9, False))  # no reference: an orphan
    store = EpisodeStore(tmp_path)
    for record in records:
        store.write(record)
    plugins = conflictbench.plugins()
    memory = report_records(records, plugins, stream=io.StringIO(), figures=False)
    out = io.StringIO()
    streamed = report_store(store, plugins, chunk=5, stream=out, figures=False)  # chunks split shared references
    key = ["conflict_episode"]
    a = memory["pairs"].sort_values(key).reset_index(drop=True)
    b = streamed["pairs"].sort_values(key).reset_index(drop=True)
    assert len(a) == 2 * 4 * 2 * 3
    pd.testing.assert_frame_equal(a, b, check_like=True)
    pd.testing.assert_frame_equal(memory["overall"], streamed["overall"])
    assert "1 conflict episode(s) have no usable stored reference" in out.getvalue()

    some = [r.episode_id for r in records if r.policy == "beta"]
    only_beta = report_store(store, plugins, episode_ids=some, stream=io.StringIO(), figures=False)
    assert set(only_beta["pairs"]["policy"]) == {"beta"}
