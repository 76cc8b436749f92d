"""`conflictbench merge`: stores written on machines without shared storage, made one."""

import numpy as np
import pytest
from testing_support import episode_record

from conflictbench.cli import main
from conflictbench.core import INFRASTRUCTURE_ERROR_PREFIX, EpisodeRecord, UserError
from conflictbench.store import EpisodeStore
from conflictbench.store.merge import merge_stores


def episode(eid: str, seed: int = 0, **kw) -> EpisodeRecord:
    rng = np.random.default_rng(seed)
    fields = dict(
        policy="pi0",
        task_id=3,
        instruction="open the drawer",
        episode_id=eid,
        steps=4,
        eef_pos=rng.normal(size=(5, 3)),
        target_pos=rng.normal(size=(5, 1, 3)),
        target_names=("bowl_1",),
        actions=rng.normal(size=(4, 7)),
        raw_actions=rng.normal(size=(4, 7)),
        conflictbench_version="0.2.0",
        plugin_version="0.1.0",
        mujoco_version="2.3.7",
    )
    return episode_record(**{**fields, **kw})


def shard(path, *records) -> EpisodeStore:
    store = EpisodeStore(path)
    for record in records:
        store.write(record)
    return store


def test_episodes_of_every_shard_land_once_and_duplicates_are_counted(tmp_path):
    a = shard(tmp_path / "a", episode("e1", 1), episode("e2", 2))
    b = shard(
        tmp_path / "b", episode("e2", 2), episode("e3", 3), episode("e4", 4, error=f"{INFRASTRUCTURE_ERROR_PREFIX}: x")
    )
    out = EpisodeStore(tmp_path / "out")
    plan = merge_stores(out, [a, b])
    assert sorted(c.episode_id for c in plan.new) == ["e1", "e2", "e3"]
    assert (plan.duplicates, len(plan.differing), plan.left_out_replays) == (1, 0, 1)
    merged = {r.episode_id: r for r in out.records()}
    assert sorted(merged) == ["e1", "e2", "e3"] and out.stored_ids() == {"e1", "e2", "e3"}
    np.testing.assert_array_equal(merged["e3"].actions, episode("e3", 3).actions)  # bytes as written
    assert not list((tmp_path / "out").rglob("*.tmp"))
    again = merge_stores(out, [a, b])  # into a store that has them: nothing new, all duplicates
    assert (len(again.new), again.duplicates) == (0, 4)


def test_a_duplicate_with_another_rollout_is_dropped_and_said(tmp_path):
    a = shard(tmp_path / "a", episode("e1", 1))
    b = shard(tmp_path / "b", episode("e1", 99))  # same id and versions, other actions: a GPU's nondeterminism
    out = EpisodeStore(tmp_path / "out")
    plan = merge_stores(out, [a, b])
    assert plan.duplicates == 1 and [(k.path.parents[2].name, d.path.parents[2].name) for k, d in plan.differing] == [
        ("a", "b")
    ]
    np.testing.assert_array_equal(out.records()[0].actions, episode("e1", 1).actions)  # the first shard's stays


def test_one_episode_played_with_other_versions_stops_the_merge_before_anything_is_written(tmp_path):
    a = shard(tmp_path / "a", episode("e1", 1), episode("e2", 2))
    b = shard(tmp_path / "b", episode("e2", 2, mujoco_version="3.3.2"), episode("e3", 3))
    out = EpisodeStore(tmp_path / "out")
    with pytest.raises(
        UserError,
        match=r"(?s)nothing merged: 1 episode.*other versions.*mujoco_version .2.3.7. vs .3.3.2.",
    ):
        merge_stores(out, [a, b])
    assert out.stored_ids() == set()


def test_the_command_says_what_it_did_and_names_mistakes_in_one_line(tmp_path, capsys):
    shard(tmp_path / "a", episode("e1", 1))
    shard(tmp_path / "b", episode("e1", 1), episode("e2", 2))
    out = tmp_path / "out"
    assert main(["merge", str(out), str(tmp_path / "a"), str(tmp_path / "b"), "--dry-run"]) == 0
    assert "would copy 2 episode(s)" in capsys.readouterr().out and not out.exists()
    assert main(["merge", str(out), str(tmp_path / "a"), str(tmp_path / "b")]) == 0
    assert "copied 2 episode(s)" in capsys.readouterr().out and EpisodeStore(out).stored_ids() == {"e1", "e2"}

    (tmp_path / "empty").mkdir()
    assert main(["merge", str(out), str(tmp_path / "missing")]) == 2
    assert main(["merge", str(out), str(tmp_path / "empty")]) == 2
    assert main(["merge", str(out), str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("conflictbench: error:") for line in err)
    assert "missing" in err[0] and "not an episode store" in err[1] and "different stores" in err[2]


def test_files_from_before_a_column_merge_and_an_unreadable_one_is_named(tmp_path, capsys):
    import pyarrow.parquet as pq

    old = shard(tmp_path / "old", episode("e1", 1))
    path = old.path_for("pi0", "e1")
    pq.write_table(pq.read_table(path).drop_columns(["code_versions", "warmup_steps"]), path)  # an older writer's
    out = EpisodeStore(tmp_path / "out")
    assert [c.episode_id for c in merge_stores(out, [old]).new] == ["e1"]
    broken = shard(tmp_path / "broken", episode("e2", 2), episode("e3", 3))
    broken.path_for("pi0", "e2").write_bytes(b"PAR1 not a parquet file")
    assert [c.episode_id for c in merge_stores(out, [broken]).new] == ["e3"]  # the damaged one left out (#42)
    assert "damaged episode file" in capsys.readouterr().err and broken.path_for("pi0", "e2").exists()


def test_an_episode_waiting_for_its_replay_counts_as_left_out_only_where_no_copy_was_kept(tmp_path):
    failed = episode("e1", 1, error=f"{INFRASTRUCTURE_ERROR_PREFIX}: the server went away")
    a = shard(tmp_path / "a", failed, episode("e2", 2, error=f"{INFRASTRUCTURE_ERROR_PREFIX}: again"))
    b = shard(tmp_path / "b", episode("e1", 1))  # played again, on another machine
    plan = merge_stores(EpisodeStore(tmp_path / "out"), [a, b])
    assert [c.episode_id for c in plan.new] == ["e1"] and plan.left_out_replays == 1  # e2 only
