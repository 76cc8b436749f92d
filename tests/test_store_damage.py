"""A damaged store says so and keeps working (#42, section 5): real Parquet files, truncated or corrupted on disk.

A damaged episode file is named in one line, set aside under ``<store>/damaged/`` (never deleted), skipped by the
report, merge, prune and the viewer, and played again by the next run; ``conflictbench store check DIR`` reads every
file and says what it found.
"""

from __future__ import annotations

import io
import struct

import numpy as np
import pytest
from testing_support import episode_record

from conflictbench.core import PolicyTraits
from conflictbench.store import EpisodeStore


def episode(eid: str, *, case: str | None = None, state: int = 0, seed: int = 0, policy: str = "noop", **kw):
    rng = np.random.default_rng(seed)
    fields = dict(
        policy=policy, suite="libero_goal", task_id=3, init_state=state, prompt="p0", instruction="open the drawer",
        case_id=case, family="spatial" if case else None, level="L1" if case else None, episode_id=eid,
        success=bool(seed % 2), steps=4, eef_pos=rng.normal(size=(5, 3)), target_pos=rng.normal(size=(5, 2, 3)),
        target_names=("a", "b"), actions=rng.normal(size=(4, 7)), raw_actions=rng.normal(size=(4, 7)),
        config_hash="h", mujoco_version="2.3.7",
    )  # fmt: skip
    return episode_record(**{**fields, **kw})


def truncate(path) -> None:
    """What a copy cut short or a crash of a tool writing in place leaves: the file's first half."""
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def corrupt_footer(path) -> None:
    """Garbage over the footer's metadata, the magic bytes and the length intact (a bad sector, a bad copy)."""
    data = bytearray(path.read_bytes())
    length = struct.unpack("<I", data[-8:-4])[0]
    start = len(data) - 8 - length
    data[start : len(data) - 8] = bytes(range(256)) * (length // 256) + bytes(length % 256)
    path.write_bytes(bytes(data))


def stored_pairs(root, policy="noop") -> EpisodeStore:
    """Two pairs (a reference and a conflict episode each) and a third reference episode."""
    store = EpisodeStore(root)
    for state in (0, 1):
        store.write(episode(f"ref{state}", state=state, seed=state, policy=policy))
        store.write(episode(f"con{state}", case=f"case{state}", state=state, seed=state + 2, policy=policy))
    store.write(episode("ref2", state=2, seed=5, policy=policy))
    return store


def set_aside(store: EpisodeStore, policy: str, eid: str):
    return store.root / "damaged" / "episodes" / policy / f"{eid}.parquet"


def test_a_report_skips_a_truncated_episode_names_it_and_sets_it_aside(tmp_path, plugins, capsys):
    from conflictbench.report import report_store

    store = stored_pairs(tmp_path / "store")
    truncate(store.path_for("noop", "con1"))
    report_store(store, plugins, stream=io.StringIO(), figures=False)  # today: ArrowInvalid, every call
    err = capsys.readouterr().err
    [line] = [x for x in err.splitlines() if "con1" in x]
    assert "damaged" in line and "damaged/episodes/noop/con1.parquet" in line and "next run plays it again" in line
    assert not store.path_for("noop", "con1").exists()
    moved = set_aside(store, "noop", "con1")
    assert moved.is_file() and "magic" in moved.with_name(moved.name + ".why").read_text().lower()
    assert store.stored_ids() == {"ref0", "ref1", "ref2", "con0"}  # the next run plays con1 again
    report_store(store, plugins, stream=io.StringIO(), figures=False)
    assert "con1" not in capsys.readouterr().err  # said once: it is no longer in the store


def test_reading_falls_back_to_file_by_file_and_keeps_every_readable_episode_in_order(tmp_path, capsys):
    store = EpisodeStore(tmp_path / "store")
    ids = [f"e{i:02d}" for i in range(12)]
    for i, eid in enumerate(ids):
        store.write(episode(eid, state=i, seed=i))
    truncate(store.path_for("noop", "e03"))
    corrupt_footer(store.path_for("noop", "e09"))
    table = store.read_table(columns=["episode_id", "init_state"])
    assert table["episode_id"].to_pylist() == [e for e in ids if e not in ("e03", "e09")]
    assert sorted(p.name for p in (store.root / "damaged" / "episodes" / "noop").glob("*.parquet")) == [
        "e03.parquet", "e09.parquet",
    ]  # fmt: skip
    assert len([x for x in capsys.readouterr().err.splitlines() if "damaged" in x]) == 2


def test_prune_skips_a_damaged_episode_and_never_deletes_it(tmp_path, capsys):
    from conflictbench.cli.prune import command as prune_command

    store = EpisodeStore(tmp_path / "store")
    store.write(episode("old", config_hash="h1", created_at="2026-11-01T10:00:00+00:00"))
    store.write(episode("new", config_hash="h2", created_at="2026-11-02T10:00:00+00:00"))
    store.write(episode("other", state=1, config_hash="h1", created_at="2026-11-01T10:00:00+00:00"))
    corrupt_footer(store.path_for("noop", "other"))
    assert prune_command([str(store.root), "--delete"], None) == 0  # today: a raw ArrowInvalid
    out, err = capsys.readouterr()
    assert out.split() == [str(store.path_for("noop", "old"))]
    assert "other" in err and set_aside(store, "noop", "other").is_file()
    assert store.stored_ids() == {"new"}


def test_merge_names_a_shards_damaged_episode_and_merges_the_rest(tmp_path, capsys):
    from conflictbench.store.merge import merge_stores

    shard = stored_pairs(tmp_path / "shard")
    truncate(shard.path_for("noop", "ref1"))
    out = EpisodeStore(tmp_path / "out")
    plan = merge_stores(out, [shard])  # today: "cannot read ... as a stored episode", nothing merged
    assert len(plan.new) == 4 and out.stored_ids() == {"ref0", "con0", "con1", "ref2"}
    [line] = [x for x in capsys.readouterr().err.splitlines() if "ref1" in x]
    assert "damaged" in line and "left out" in line and "store check --quarantine" in line
    assert shard.path_for("noop", "ref1").exists()  # a shard is only read: named, left in place


def test_the_viewer_skips_a_damaged_episode(tmp_path, plugins, capsys):
    from conflictbench.view import Selection, build_site

    store = stored_pairs(tmp_path / "store")
    truncate(store.path_for("noop", "con0"))
    built = build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    assert built.pairs == 1  # con1 and its reference; con0's pair is gone with it
    assert set_aside(store, "noop", "con0").is_file()


def test_records_whose_arrays_cannot_be_read_are_set_aside_and_the_loader_says_so_in_one_line(tmp_path):
    """A file whose key columns read but whose arrays do not (damage inside a data page) is caught where the arrays
    are read: set aside, and the command that met it ends in one line; the next call goes on without it."""
    from conflictbench.core import UserError

    store = stored_pairs(tmp_path / "store")
    path = store.path_for("noop", "ref1")
    data = bytearray(path.read_bytes())
    data[4:40] = b"\xff" * 36  # the first column's first page, inside the file: the footer is intact
    path.write_bytes(bytes(data))
    with pytest.raises(UserError, match="ref1.*damaged.*again"):
        store.load([("ref1", "noop"), ("ref0", "noop")])
    assert set_aside(store, "noop", "ref1").is_file()
    assert [r.episode_id for r in store.load([("ref0", "noop")])] == ["ref0"]


def _items(count: int):
    """Real planned items (episode specs with their jobs) for the noop policy."""
    import conflictbench
    from conflictbench.policies import NoopPolicy
    from conflictbench.sim.episode_rows import make_items
    from conflictbench.sim.plan import EpisodeSpec

    specs = [EpisodeSpec("libero_goal", 3, state, "p0", "open the drawer") for state in range(count)]
    return make_items(specs, PolicyTraits(NoopPolicy()), conflictbench.plugins(), "noop", "h", 7, "h")


def test_the_next_run_plays_a_damaged_episode_again(tmp_path, capsys):
    """Planning reads names, and checks each planned stored file's Parquet footer (magic at both ends, a length
    that fits): a truncated episode is set aside and played again, not counted as stored."""
    from conflictbench.sim.planning import RunIdentity, left_to_play

    items = _items(3)
    store = EpisodeStore(tmp_path / "store")
    for item in items:
        store.write(episode(item.job.episode_id, config_hash="h"))
    truncate(store.path_for("noop", items[1].job.episode_id))
    identity = RunIdentity(config_hash="h", sampling_hash="h", code_versions=(), model_stack=())
    todo, result = left_to_play(store, items, identity, "noop", None, retry=False)
    assert [i.job.episode_id for i in todo] == [items[1].job.episode_id]  # today: [] (stored by name)
    assert result.already_stored == 2
    eid = items[1].job.episode_id
    [line] = [x for x in capsys.readouterr().err.splitlines() if eid in x]
    assert "this run plays it again" in line and set_aside(store, "noop", eid).is_file()


def test_store_check_reads_every_file_and_says_what_it_found(tmp_path, capsys):
    from conflictbench.cli import main

    store = stored_pairs(tmp_path / "store")
    store.write(episode("waiting", state=4, error="server: gone", error_kind="server"))
    assert main(["store", "check", str(store.root)]) == 0
    assert "6 episode files read: all readable" in capsys.readouterr().out
    truncate(store.path_for("noop", "ref0"))
    corrupt_footer(store.replay_path_for("noop", "waiting"))
    assert main(["store", "check", str(store.root)]) == 1
    out = capsys.readouterr().out
    assert "2 of 6 episode files damaged" in out
    assert len([x for x in out.splitlines() if "episodes/noop/ref0.parquet" in x]) == 1
    assert len([x for x in out.splitlines() if "replay/noop/waiting.parquet" in x]) == 1
    assert store.path_for("noop", "ref0").exists()  # a check changes nothing unless asked
    assert main(["store", "check", str(store.root), "--quarantine"]) == 1
    assert set_aside(store, "noop", "ref0").is_file()
    assert (store.root / "damaged" / "replay" / "noop" / "waiting.parquet").is_file()
    capsys.readouterr()
    assert main(["store", "check", str(store.root)]) == 0
    assert "4 episode files read: all readable; 2 set aside earlier" in capsys.readouterr().out


def test_store_check_finds_damage_inside_a_data_page_by_its_checksum(tmp_path, capsys):
    """Episodes are written with page checksums: a flipped byte in an array is found by a full read."""
    from conflictbench.cli import main

    store = EpisodeStore(tmp_path / "store")
    store.write(episode("a", steps=300, eef_pos=np.zeros((301, 3)), actions=np.ones((300, 7)),
                        raw_actions=np.ones((300, 7)), target_pos=np.zeros((301, 2, 3))))  # fmt: skip
    path = store.path_for("noop", "a")
    import pyarrow.parquet as pq

    meta = pq.read_metadata(path)
    actions = next(
        meta.row_group(0).column(i) for i in range(meta.num_columns) if meta.row_group(0).column(i).path_in_schema
        .startswith("actions")
    )  # fmt: skip
    data = bytearray(path.read_bytes())
    start = actions.dictionary_page_offset if actions.has_dictionary_page else actions.data_page_offset
    data[start + actions.total_compressed_size - 16] ^= 0xFF  # inside the last page's values, headers intact
    path.write_bytes(bytes(data))
    assert main(["store", "check", str(store.root)]) == 1
    [line] = [x for x in capsys.readouterr().out.splitlines() if "episodes/noop/a.parquet" in x]
    assert "checksum" in line


def test_store_check_of_a_folder_that_is_not_a_store_is_one_line(tmp_path):
    from conflictbench.cli import main

    assert main(["store", "check", str(tmp_path / "nothing")]) == 2
    assert main(["store", "frobnicate", str(tmp_path)]) == 2


def test_damage_that_cannot_be_set_aside_is_still_skipped(tmp_path, capsys):
    """Where the file cannot be moved (a read-only store; here a file where the quarantine folder would go), it
    stays where it is and the read goes on without it."""
    store = stored_pairs(tmp_path / "store")
    truncate(store.path_for("noop", "ref2"))
    (store.root / "damaged").write_text("in the way")
    table = store.read_table(columns=["episode_id"])
    assert sorted(table["episode_id"].to_pylist()) == ["con0", "con1", "ref0", "ref1"]
    assert store.path_for("noop", "ref2").exists()
    assert "cannot set it aside" in capsys.readouterr().err


def test_an_unreadable_episode_is_not_quarantined_when_it_only_vanished(tmp_path):
    """A file removed meanwhile (another job's prune) is not damage: nothing is set aside."""
    store = stored_pairs(tmp_path / "store")
    files = store.files()
    store.path_for("noop", "ref2").unlink()
    from conflictbench.store.check import read_intact

    tables = read_intact(files, ["episode_id"])
    assert sorted(t for tb in tables for t in tb["episode_id"].to_pylist()) == ["con0", "con1", "ref0", "ref1"]
    assert not (store.root / "damaged").exists()


# -- a full disk ---------------------------------------------------------------------------------------------------


@pytest.fixture
def small_disk(tmp_path):
    """A real tmpfs of 256 KiB mounted as the store (root only); skipped where this process cannot mount one (the
    RLIMIT_FSIZE test below takes the same path without privileges)."""
    yield from mounted_tmpfs(tmp_path / "small")


def mounted_tmpfs(folder, size: str = "256k"):
    """A tmpfs mounted at ``folder`` for as long as the generator runs (a fixture's body)."""
    import subprocess

    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                             capture_output=True, text=True)  # fmt: skip
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def big_episode(eid: str, seed: int = 0):
    """About 60 kB on disk (random floats do not compress): four fill the small disk."""
    rng = np.random.default_rng(seed)
    return episode(eid, steps=300, eef_pos=rng.random((301, 3)), actions=rng.random((300, 7)),
                   raw_actions=rng.random((300, 7)), target_pos=rng.random((301, 2, 3)))  # fmt: skip


def leftovers(root) -> list[str]:
    return sorted(p.name for p in root.rglob("*") if p.name.endswith(".tmp"))


def test_a_full_disk_stops_writing_in_one_line_and_leaves_no_temporary(small_disk):
    from conflictbench.core import StoreFull

    store = EpisodeStore(small_disk)
    written = []
    with pytest.raises(StoreFull) as caught:  # today: OSError [Errno 28] from pyarrow
        for i in range(20):
            store.write(big_episode(f"e{i:02d}", seed=i))
            written.append(f"e{i:02d}")
    message = str(caught.value)
    assert "\n" not in message and str(small_disk) in message and "No space left on device" in message
    assert "run the same command again" in message and caught.value.exit_code == 3
    assert 1 <= len(written) < 20 and leftovers(small_disk) == []
    assert store.stored_ids() == set(written)  # every episode acknowledged is whole
    assert len(store.read_table(columns=["episode_id"])) == len(written)


def test_a_merge_into_a_full_disk_stops_in_one_line_and_leaves_no_temporary(small_disk, tmp_path):
    from conflictbench.core import StoreFull
    from conflictbench.store.merge import merge_stores

    shard = EpisodeStore(tmp_path / "shard")
    for i in range(8):
        shard.write(big_episode(f"e{i:02d}", seed=i))
    with pytest.raises(StoreFull):  # today: OSError [Errno 28], and a half-copied temporary left in OUT
        merge_stores(EpisodeStore(small_disk), [shard])
    assert leftovers(small_disk) == []
    assert all(footer_ok for footer_ok in (p.stat().st_size > 0 for p in EpisodeStore(small_disk).kept_files()))


def test_a_claim_on_a_full_disk_stops_in_one_line_and_leaves_no_temporary(small_disk):
    from conflictbench.core import StoreFull

    filler = small_disk / "filler"
    with pytest.raises(OSError), open(filler, "wb") as out:
        while True:
            out.write(b"\0" * 65536)
            out.flush()
    store = EpisodeStore(small_disk)
    (small_disk / "claims").mkdir(exist_ok=True)
    with pytest.raises(StoreFull):
        for i in range(200):  # a directory entry or two may still fit
            store.claim(f"e{i:03d}")
    assert leftovers(small_disk) == []


_FSIZE_CHILD = """
import resource, signal, sys
sys.path.insert(0, sys.argv[2])
from test_store_damage import big_episode
from conflictbench.core import StoreFull
from conflictbench.store import EpisodeStore
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write then fails with EFBIG instead of killing the process
resource.setrlimit(resource.RLIMIT_FSIZE, (30_000, 30_000))
try:
    EpisodeStore(sys.argv[1]).write(big_episode("e00"))
except StoreFull as exc:
    print("STOREFULL", exc)
"""


def test_a_file_size_limit_stops_writing_in_one_line_and_leaves_no_temporary(tmp_path):
    """The same path without privileges: a file size limit (RLIMIT_FSIZE) makes the write fail with EFBIG."""
    import subprocess
    import sys
    from pathlib import Path

    store = tmp_path / "store"
    out = subprocess.run([sys.executable, "-c", _FSIZE_CHILD, str(store), str(Path(__file__).parent)],
                         capture_output=True, text=True, timeout=60)  # fmt: skip
    assert out.stdout.startswith("STOREFULL no room left in the episode store"), out.stdout + out.stderr[-2000:]
    assert "File too large" in out.stdout and leftovers(store) == []
    assert EpisodeStore(store).stored_ids() == set()


def test_an_episode_landed_is_synced_with_its_directory_after_the_rename(tmp_path, monkeypatch):
    """A rename is durable only once its directory is synced: after os.replace, os.fsync on the folder's descriptor
    (observed at the OS boundary: each fsync's target, read from /proc/self/fd)."""
    import os

    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return real_fsync(fd)

    def replace(src, dst, **kw):
        events.append(("replace", str(dst)))
        return real_replace(src, dst, **kw)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    store = EpisodeStore(tmp_path / "store")
    final = store.write(episode("a"))
    landed = next(i for i, e in enumerate(events) if e[0] == "replace" and e[1] in (str(final), final.name))
    after = events[landed + 1 :]  # (renamed within the folder's descriptor: named by the file's name alone)
    assert ("fsync", str(final.parent)) in after  # today: only the file is synced, before the rename


@pytest.mark.sim
@pytest.mark.e2e
def test_a_run_on_a_disk_that_fills_ends_in_one_line_and_the_same_command_resumes(cli, tmp_path):
    """A real run on a real tmpfs (2 MiB, filled but for 64 KiB: room for Hydra's files and a few episodes): it stops
    with exit code 3 and one line saying what it stored, what to free and how to resume; no temporary is left; once
    space is freed, the same command plays the rest."""
    import subprocess

    small = tmp_path / "small"
    small.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(small)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        filler = small / "filler"
        with pytest.raises(OSError), open(filler, "wb") as out:
            while True:
                out.write(b"\0" * 65536)
                out.flush()
        with open(filler, "r+b") as out:
            out.truncate(filler.stat().st_size - 64 * 1024)
        command = ("model=noop", "suite=physical", "level=L1", "run.libero_suites=[libero_object]", "run.max_steps=3",
                   "run.init_states=3", f"run.out={small}", "run.report=false")  # fmt: skip
        first = cli(*command)
        assert first.returncode == 3, first.stderr[-3000:]  # today: 1, with OSError's traceback
        assert "Traceback" not in first.stderr, first.stderr[-3000:]
        last = first.stderr.strip().splitlines()[-1]
        stored = EpisodeStore(small).stored_ids()
        assert 0 < len(stored) < 6, first.stderr[-3000:]
        assert last.startswith(f"conflictbench: error: no room left in the episode store {small}"), last
        assert f"this run stored {len(stored)} episode(s)" in last and "run the same command again" in last
        assert leftovers(small) == [], first.stderr[-3000:]
        filler.unlink()
        second = cli(*command)
        assert second.returncode == 0, second.stderr[-3000:]
        assert f"{6 - len(stored)} played, {len(stored)} already stored" in second.stderr
    finally:
        subprocess.run(["umount", "-l", str(small)], check=False)


def test_a_file_this_version_cannot_cast_is_not_set_aside(tmp_path):
    """Not damage: a column of another type (a newer writer's, say) fails the cast to this version's schema. Reads
    stop in one line naming the file (not Arrow's traceback), and the file stays where it is (a newer conflictbench
    reads it); tests/test_store_trust.py runs the commands."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from conflictbench.store.schema import records_to_table

    store = stored_pairs(tmp_path / "store")
    path = store.path_for("noop", "ref2")
    table = records_to_table([episode("ref2", state=2)])
    index = table.schema.get_field_index("eef_pos")
    pq.write_table(table.set_column(index, "eef_pos", pa.array(["a newer encoding"])), path)
    from conflictbench.core import UserError

    with pytest.raises(UserError, match="ref2.parquet is not readable by this version.*newer.* conflictbench"):
        store.read_table()
    assert path.exists() and not (store.root / "damaged").exists()
