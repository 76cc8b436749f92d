"""The episode store: real Parquet files, atomic writes, claims between concurrent jobs."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import types

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
from testing_support import episode_record

from conflictbench.core import EpisodeRecord
from conflictbench.store import SCHEMA, EpisodeStore, claims


def record(eid: str, h: int = 4, k: int = 2, policy: str = "noop", seed: int = 0, **kw) -> EpisodeRecord:
    rng = np.random.default_rng(seed)
    fields = dict(
        policy=policy,
        task_id=3,
        init_state=1,
        prompt="p1",
        instruction="put it there",
        episode_id=eid,
        success=bool(seed % 2),
        steps=h,
        eef_pos=rng.normal(size=(h + 1, 3)),
        target_pos=rng.normal(size=(h + 1, k, 3)),
        target_names=tuple(f"obj_{i}" for i in range(k)),
        actions=rng.normal(size=(h, 7)),
        raw_actions=rng.normal(size=(h, 7)),
        mujoco_version="2.3.7",
    )
    return episode_record(**{**fields, **kw})


def assert_same(a: EpisodeRecord, b: EpisodeRecord) -> None:
    for name in SCHEMA.names:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.shape == y.shape and np.array_equal(x, y), name
        else:
            assert x == y, name


def test_round_trip_keeps_every_column_bit_for_bit(tmp_path):
    store = EpisodeStore(tmp_path)
    originals = [
        record("a", h=5, k=2, seed=1),
        record("b", h=0, k=1, seed=2, case_id="c1", family="spatial", level="L2"),
        record("c", h=3, k=0, seed=3, error="policy returned NaN", error_kind="policy"),
        record("d", seed=4, error="simulator error: x", error_kind="simulator", sim_warnings=("mjWARN_BADQACC x2",)),
    ]
    for r in originals:
        store.write(r)
    back = {r.episode_id: r for r in store.records()}
    assert set(back) == {"a", "b", "c", "d"}
    for r in originals:
        assert_same(r, back[r.episode_id])
    assert back["b"].eef_pos.shape == (1, 3) and back["b"].actions.shape == (0, 7)
    assert back["c"].target_pos.shape == (4, 0, 3)


def test_files_are_plain_parquet_readable_without_conflictbench(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("a", seed=1))
    store.write(record("b", seed=2, policy="random"))
    frame = pd.concat([pd.read_parquet(p) for p in sorted((tmp_path / "episodes").glob("*/*.parquet"))])
    assert sorted(frame["policy"]) == ["noop", "random"]
    first = pq.read_table(store.path_for("noop", "a"))
    assert first.schema.equals(SCHEMA, check_metadata=False)
    eef = np.array(first.column("eef_pos").to_pylist()[0])
    np.testing.assert_array_equal(eef, record("a", seed=1).eef_pos)


def test_a_store_written_before_the_settings_column_reads_it_as_empty(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("a", seed=1))
    path = store.path_for("noop", "a")
    pq.write_table(pq.read_table(path).drop_columns(["policy_settings"]), path)  # as an older conflictbench wrote it
    [read] = EpisodeStore(tmp_path).records()
    assert read.policy_settings == "" and read.episode_id == "a"


def test_a_store_written_before_the_warmup_column_reads_it_as_unknown(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("a", seed=1, warmup_steps=10))
    assert EpisodeStore(tmp_path).records()[0].warmup_steps == 10
    path = store.path_for("noop", "a")
    pq.write_table(pq.read_table(path).drop_columns(["warmup_steps"]), path)
    assert EpisodeStore(tmp_path).records()[0].warmup_steps is None


def test_select_episodes_by_id(tmp_path):
    store = EpisodeStore(tmp_path)
    for i in range(4):
        store.write(record(f"e{i}", seed=i))
    assert {r.episode_id for r in store.records(episode_ids=["e1", "e3", "missing"])} == {"e1", "e3"}
    assert store.stored_ids() == {"e0", "e1", "e2", "e3"} and len(store) == 4


def test_rewriting_an_episode_replaces_it_and_leaves_no_temporary(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("a", seed=1))
    store.write(record("a", seed=2))
    assert len(store) == 1
    assert_same(store.records()[0], record("a", seed=2))
    assert not list((tmp_path / "episodes").rglob("*.tmp"))


def test_half_written_files_of_dead_processes_are_ignored_and_cleaned(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("a"))
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    tmp = tmp_path / "episodes" / "noop" / f".b.parquet.{int(dead.stdout)}@{store._host}.tmp"
    tmp.write_bytes(b"PAR1 truncated")
    assert store.stored_ids() == {"a"}
    assert store.clean_stale_temporaries() == 1 and not tmp.exists()


def test_claims_exclude_live_processes_and_are_taken_over_from_dead_ones(tmp_path):
    store = EpisodeStore(tmp_path)
    assert store.claim("e1")
    assert store.claim("e1")  # our own claim
    assert store.held_by_others(["e1"]) == set()
    store.release("e1")

    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (tmp_path / "claims" / "e2.claim").write_text(f"{os.uname().nodename} {other.pid} 0\n")
        assert not store.claim("e2")
        assert store.held_by_others(["e1", "e2"]) == {"e2"}
    finally:
        other.kill()
        other.wait()
    assert store.claim("e2")  # its owner is gone

    (tmp_path / "claims" / "e3.claim").write_text("another-host 1 a1\n")
    assert not store.claim("e3")  # a process on another machine cannot be checked: respected...


def test_another_machines_claim_holds_while_it_is_renewed_whatever_its_clock_says(tmp_path, monkeypatch):
    """A lease that needs no agreeing clocks: another machine's claim holds while its token changes, and is taken
    over once this process has seen it unchanged for the TTL (a job the scheduler killed). This process's clock is
    the test's (real sleeps of 0.3 s against a TTL of 0.5 s could overrun it on a busy machine)."""
    ours = [1000.0]
    monkeypatch.setattr(claims, "time", types.SimpleNamespace(monotonic=lambda: ours[0]))
    store = EpisodeStore(tmp_path)
    store.remote_claim_ttl_s = 0.5
    claim = tmp_path / "claims" / "e.claim"
    claim.parent.mkdir(parents=True)
    # Their clock is a day behind ours (what the old time stamps read as a claim long dead), then a day ahead.
    for token in (f"{time.time() - 86400:.3f}", "b2", f"{time.time() + 86400:.3f}", "d4"):
        claim.write_text(f"another-host 1 {token}\n")  # a renewal: a new token
        assert not store.claim("e") and store.held_by_others(["e"]) == {"e"}
        ours[0] += 0.3  # more than the TTL in all, never the TTL unchanged
    assert not store.claim("e")  # still inside the TTL since the last renewal was seen
    ours[0] += 0.19
    assert not store.claim("e")
    ours[0] += 0.02
    assert store.claim("e")  # unchanged for longer than the TTL: its owner is gone
    assert claim.read_text().startswith(os.uname().nodename)


def test_refreshing_renews_only_this_processs_own_claims(tmp_path):

    store = EpisodeStore(tmp_path)
    assert store.claim("mine")
    theirs = "another-host 1 c3\n"
    (tmp_path / "claims" / "theirs.claim").write_text(theirs)
    before = (tmp_path / "claims" / "mine.claim").read_text().split()[2]
    assert store.refresh_claims(["mine", "theirs", "unclaimed"]) == {"theirs", "unclaimed"}  # not (or no longer) ours
    assert (tmp_path / "claims" / "mine.claim").read_text().split()[2] != before  # renewed: a new token
    assert (tmp_path / "claims" / "theirs.claim").read_text() == theirs  # never overwritten
    assert not (tmp_path / "claims" / "unclaimed.claim").exists()
    assert not list((tmp_path / "claims").glob(".*.tmp"))


def test_a_claim_taken_over_from_a_job_that_looked_dead_stays_with_the_new_owner(tmp_path):
    from conflictbench.store.episodes import ClaimKeeper

    old = EpisodeStore(tmp_path)
    assert old.claim("e")
    keeper = ClaimKeeper(old)
    keeper.hold("e")
    # the old job stalled past the TTL; a job on another machine took the episode over
    (tmp_path / "claims" / "e.claim").write_text("another-host 1 e5\n")
    keeper.refresh()
    assert keeper.lost == {"e"}  # the runner stores nothing of it
    old.release("e")
    assert (tmp_path / "claims" / "e.claim").read_text().startswith("another-host")  # still theirs
    assert not EpisodeStore(tmp_path).claim("e")


def test_the_claim_keeper_renews_from_its_own_thread(tmp_path):
    store = EpisodeStore(tmp_path)
    store.claim_refresh_s = 0.05
    from conflictbench.store.episodes import ClaimKeeper

    assert store.claim("e")
    first = (tmp_path / "claims" / "e.claim").read_text().split()[2]
    with ClaimKeeper(store) as keeper:
        keeper.hold("e")
        time.sleep(0.3)  # the main thread does nothing meanwhile
    assert (tmp_path / "claims" / "e.claim").read_text().split()[2] != first and not keeper.lost


def test_empty_store_reads_as_nothing(tmp_path):
    store = EpisodeStore(tmp_path / "missing")
    assert store.records() == [] and len(store) == 0
    assert store.read_table().num_rows == 0


@pytest.mark.parametrize("bad", ["eef_pos", "actions"])
def test_schema_rejects_arrays_of_the_wrong_width(tmp_path, bad):
    wrong = record("a")
    setattr(wrong, bad, np.zeros((3, 5)))
    with pytest.raises(ValueError, match=f"column {bad}"):
        EpisodeStore(tmp_path).write(wrong)


@pytest.mark.sim  # LIBERO's base tasks
def test_an_episode_another_job_landed_after_the_snapshot_is_not_played_twice(tmp_path, plugins):
    """Job B's list of stored episodes is a snapshot; job A may write an episode and release its
    claim after it. B then wins the claim, and must still see the file and skip the episode."""
    from testing_support import reference_spec

    from conflictbench.core import PolicyTraits
    from conflictbench.policies import NoopPolicy
    from conflictbench.sim.plan import config_hash
    from conflictbench.sim.runner import Runner, RunResult
    from conflictbench.sim.slots import EpisodeQueue, Slot

    store = EpisodeStore(tmp_path)
    runner = Runner(plugins, plugins.policy("noop"), None, store=store, progress=False)
    traits = PolicyTraits(NoopPolicy())
    runner.config_hash = config_hash("noop", None, traits)
    first, second = runner.jobs([reference_spec("libero_goal", 0, state) for state in (0, 1)], traits)
    snapshot = store.stored_ids()
    store.write(record(first.job.episode_id))  # the other job finished it, and let go of it

    result = RunResult()
    chosen = runner._next_item(Slot(0), EpisodeQueue([first, second]), [], snapshot, set(), result)
    assert chosen is second
    assert result.played_elsewhere == 1
    assert store.held_by_others([first.job.episode_id]) == set()
    assert not (tmp_path / "claims" / f"{first.job.episode_id}.claim").exists()
    assert (tmp_path / "claims" / f"{second.job.episode_id}.claim").exists()


def _claim_all(root: str, count: int, barrier, results) -> None:
    store = EpisodeStore(root)
    barrier.wait()
    results.put({i for i in range(count) if store.claim(f"ep{i:05d}")})


def test_two_processes_claiming_the_same_episodes_at_once_never_both_win(tmp_path):
    """Jobs of a sweep start together and claim in the same order: each episode goes to exactly one."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    count, barrier, results = 1500, ctx.Barrier(2), ctx.Queue()
    jobs = [ctx.Process(target=_claim_all, args=(str(tmp_path), count, barrier, results)) for _ in range(2)]
    for job in jobs:
        job.start()
    first, second = results.get(timeout=120), results.get(timeout=120)
    for job in jobs:
        job.join(timeout=30)
    assert first & second == set() and len(first | second) == count
    assert not list((tmp_path / "claims").glob(".*.tmp"))


def test_temporaries_of_another_machine_are_left_alone(tmp_path):
    store = EpisodeStore(tmp_path)
    folder = tmp_path / "episodes" / "noop"
    folder.mkdir(parents=True)
    dead_here = folder / f".a.parquet.999999999@{store._host}.tmp"  # no such pid on this machine
    elsewhere = folder / ".b.parquet.999999999@another-host.example.tmp"  # a live write, maybe
    for tmp in (dead_here, elsewhere):
        tmp.write_bytes(b"half")
    assert store.clean_stale_temporaries() == 1
    assert not dead_here.exists() and elsewhere.exists()


def test_an_episode_failing_twice_the_same_way_not_by_the_policy_is_left_waiting(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    store.write(record("e1", error="infrastructure error: HTTP 500", error_kind="server"))
    assert store.replay_ids() == {"e1"} and store.repeated_failure_ids() == set()
    store.write(record("e1", error="infrastructure error: HTTP 503", error_kind="server"))  # another failure
    assert store.repeated_failure_ids() == set()
    store.write(record("e1", error="infrastructure error: HTTP 503", error_kind="server"))
    assert store.repeated_failure_ids() == {"e1"}
    store.write(record("e1", error="infrastructure error: HTTP 503", error_kind="client"))  # same text, other kind
    assert store.repeated_failure_ids() == set()
    store.write(record("e1", error="infrastructure error: HTTP 503", error_kind="client"))
    assert store.repeated_failure_ids() == {"e1"}
    store.write(record("e1"))  # played at last
    assert store.replay_ids() == set() and store.repeated_failure_ids() == set() and store.stored_ids() == {"e1"}
    policy_failures = [record("e2", error="policy returned NaN", error_kind="policy") for _ in range(2)]
    for failure in policy_failures:
        store.write(failure)  # the model's own failure: stored for good, scored
    assert "e2" in store.stored_ids() and store.repeated_failure_ids() == set()


def test_a_store_written_before_the_error_kind_column_reads_its_kinds_from_the_text(tmp_path):
    store = EpisodeStore(tmp_path)
    store.write(record("a", error="simulator error: MuJoCo died"))
    path = store.replay_path_for("noop", "a")
    pq.write_table(pq.read_table(path).drop_columns(["error_kind"]), path)  # as an older conflictbench wrote it
    [read] = EpisodeStore(tmp_path).records()
    assert read.error_kind is None and read.failure_kind == "simulator" and read.infrastructure_failed
