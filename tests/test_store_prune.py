"""`conflictbench prune`: episodes played again under a newer identity are superseded; other models are not."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from conflictbench.cli.prune import command as prune_command
from conflictbench.core import EpisodeRecord
from conflictbench.store import EpisodeStore
from conflictbench.store.prune import superseded


def episode(eid: str, config_hash: str, created_at: str, **kw) -> EpisodeRecord:
    return EpisodeRecord(
        policy=kw.pop("policy", "pi0"), suite="libero_goal", task_id=1, init_state=kw.pop("init_state", 0),
        prompt="p0", instruction="open the drawer", prompt_text="open the drawer", episode_id=eid,
        config_hash=config_hash, created_at=created_at, eef_pos=np.zeros((2, 3)), target_pos=np.zeros((2, 1, 3)),
        target_names=("drawer",), actions=np.zeros((1, 7)), raw_actions=np.zeros((1, 7)), **kw,
    )  # fmt: skip


def test_the_older_identities_of_one_chosen_episode_are_superseded_and_removed_when_asked(tmp_path, capsys):
    store = EpisodeStore(tmp_path / "results")
    checkpoint_a, checkpoint_b = '{"checkpoint": "a1b2"}', '{"checkpoint": "c3d4"}'
    episodes = [
        episode("old-code", "h1", "2026-11-01T10:00:00+00:00", policy_identity=checkpoint_a),
        episode("new-code", "h2", "2026-11-02T10:00:00+00:00", policy_identity=checkpoint_a),  # played again
        episode("other-state", "h1", "2026-11-01T10:00:00+00:00", policy_identity=checkpoint_a, init_state=1),
        episode("other-model", "h3", "2026-11-01T09:00:00+00:00", policy_identity=checkpoint_b),  # not a successor
        episode("noop-old", "n1", "2026-11-01T10:00:00+00:00", policy="noop"),
        episode("noop-new", "n2", "2026-11-03T10:00:00+00:00", policy="noop"),
    ]
    for record in episodes:
        store.write(record)
    store.write(replace(episodes[0], episode_id="waiting-old", error="server: gone", error_kind="server"))
    assert [(s.policy, s.episode_id) for s in superseded(store)] == [
        ("noop", "noop-old"),
        ("pi0", "old-code"),
        ("pi0", "waiting-old"),
    ]
    assert prune_command([str(store.root)], None) == 0  # lists, removes nothing
    out, err = capsys.readouterr()
    assert len(out.splitlines()) == 3 and len(store) == 7
    assert "3 of 7 episodes superseded (--delete removes them): noop 1, pi0 2;" in err
    assert prune_command([str(store.root), "--delete"], None) == 0
    assert sorted(store.stored_ids()) == ["new-code", "noop-new", "other-model", "other-state"]
    assert not store.replay_ids() and superseded(store) == []
    assert prune_command([str(store.root)], None) == 0
    assert "none of the 4 episodes" in capsys.readouterr().err


def test_a_capped_run_supersedes_no_full_one_and_rows_from_before_the_columns_join_their_successors(tmp_path):
    store = EpisodeStore(tmp_path / "results")
    store.write(episode("full", "h1", "2026-11-01T10:00:00+00:00", max_steps=300))
    store.write(episode("capped", "h2", "2026-11-02T10:00:00+00:00", max_steps=40))  # run.max_steps=40: a smoke test
    assert superseded(store) == []
    older = EpisodeStore(tmp_path / "older")  # written before policy_identity and conflict_suite: null there
    older.write(episode("before-columns", "h0", "2026-10-01T10:00:00+00:00", conflict_suite=None))
    older.write(episode("today", "h3", "2026-11-03T10:00:00+00:00", policy_identity='{"checkpoint": "a1"}'))
    assert [s.episode_id for s in superseded(older)] == ["before-columns"]
