"""What a read of a store believes of a file (#42, section 5, after review): its page checksums, its cast to this
version's schema, and that it holds the one episode its place names. Real Parquet files, damaged or crafted on
disk; every command that meets one says so in one line and goes on (or, for a file of another version, stops)."""

from __future__ import annotations

import io

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from test_store_damage import big_episode, episode, mounted_tmpfs, set_aside, stored_pairs

from conflictbench.cli import main
from conflictbench.core import UserError
from conflictbench.store import EpisodeStore
from conflictbench.store.schema import records_to_table


@pytest.fixture
def small_disk(tmp_path):
    """A real 256 KiB tmpfs (root only; skipped elsewhere)."""
    yield from mounted_tmpfs(tmp_path / "small")


def flip_a_value(path, column: str = "eef_pos") -> None:
    """One bit flipped near the end of ``column``'s chunk: inside its last page's values, every header intact (read
    without checksums, the file gives another number, no error)."""
    meta = pq.read_metadata(path).row_group(0)
    [chunk] = [meta.column(i) for i in range(meta.num_columns) if meta.column(i).path_in_schema.startswith(column)]
    start = chunk.dictionary_page_offset if chunk.has_dictionary_page else chunk.data_page_offset
    data = bytearray(path.read_bytes())
    data[start + chunk.total_compressed_size - 3] ^= 0x10
    path.write_bytes(bytes(data))


def lines_naming(err: str, name: str) -> list[str]:
    return [x for x in err.splitlines() if name in x]


# -- 1. page checksums on every read ---------------------------------------------------------------------------------
def test_a_value_flipped_inside_a_data_page_is_damage_named_set_aside_and_left_out(tmp_path, plugins, capsys):
    from conflictbench.report import report_store

    store = stored_pairs(tmp_path / "store")
    flip_a_value(store.path_for("noop", "con1"))
    report_store(store, plugins, stream=io.StringIO(), figures=False)
    [line] = lines_naming(capsys.readouterr().err, "con1.parquet")  # today: no line, a changed value reported
    assert "checksum" in line and "set aside as damaged/episodes/noop/con1.parquet" in line
    assert set_aside(store, "noop", "con1").is_file() and store.stored_ids() == {"ref0", "ref1", "ref2", "con0"}


# -- 2. a file this version cannot cast ------------------------------------------------------------------------------
def newer_file(store: EpisodeStore, eid: str = "ref2", state: int = 2):
    """``steps`` as a list: what a newer writer might store, which this version's schema cannot cast."""
    path = store.path_for("noop", eid)
    table = records_to_table([episode(eid, state=state)])
    index = table.schema.get_field_index("steps")
    pq.write_table(table.set_column(index, "steps", pa.array([[4, 5]])), path)
    return path


@pytest.mark.parametrize("command", [["report"], ["view", "--videos", "0", "--no-progress"]])
def test_a_file_of_another_version_stops_report_and_view_in_one_line_naming_it(tmp_path, capsys, command):
    store = stored_pairs(tmp_path / "store")
    path = newer_file(store)
    assert main([command[0], str(store.root), *command[1:]]) == 2  # today: ArrowNotImplementedError's traceback
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert "episodes/noop/ref2.parquet" in err and "newer" in err and "conflictbench version" in err, err
    assert path.exists() and not (store.root / "damaged").exists()


def test_store_check_says_a_file_of_another_version_is_not_readable_by_this_one_and_never_moves_it(tmp_path, capsys):
    store = stored_pairs(tmp_path / "store")
    path = newer_file(store)
    assert main(["store", "check", str(store.root), "--quarantine"]) == 1
    out = capsys.readouterr().out
    [line] = lines_naming(out, "episodes/noop/ref2.parquet")
    assert "not readable by this version" in line and "set aside" not in line, out  # today: damaged, moved
    assert path.exists() and not (store.root / "damaged").exists()


# -- 3. a file holds the episode its place names ---------------------------------------------------------------------
@pytest.mark.parametrize("what", ["another schema", "a copy of ref0", "another policy"])
def test_a_file_that_does_not_hold_the_episode_its_place_names_is_damage(tmp_path, plugins, capsys, what):
    from conflictbench.report import report_store

    store = stored_pairs(tmp_path / "store")
    path = store.path_for("noop", "ref2")
    if what == "another schema":
        pq.write_table(pa.table({"x": [1, 2, 3]}), path)
    elif what == "a copy of ref0":
        path.write_bytes(store.path_for("noop", "ref0").read_bytes())
    else:  # every file of noop/ holding policy "other": a report made pairs of rows no file holds at their place
        for eid in ("ref0", "ref1", "con0", "con1", "ref2"):
            target = store.path_for("noop", eid)
            [record] = store.records([eid])
            pq.write_table(records_to_table([record.__class__(**{**record.__dict__, "policy": "other"})]), target)
    frames = report_store(store, plugins, stream=io.StringIO(), figures=False)  # today: 7 episodes; ref0 twice;
    err = capsys.readouterr().err  # KeyError 'con1'
    assert lines_naming(err, "ref2.parquet") and ("not the one its place names" in err or "rows" in err), err
    assert set_aside(store, "noop", "ref2").is_file()
    assert "ref2" not in store.stored_ids()
    counted = store.read_table(columns=["episode_id"])["episode_id"].to_pylist()
    assert sorted(counted) == sorted(set(counted)) and "ref2" not in counted
    assert frames is not None


def test_an_episode_that_vanished_between_listing_and_loading_is_left_out_without_a_key_error(tmp_path, plugins):
    from conflictbench.report.from_store import report_store

    store = stored_pairs(tmp_path / "store")

    class Vanishing(EpisodeStore):
        """The store as another job's prune leaves it: con1 removed after the keys were read."""

        def load(self, keys):
            with_con1 = list(keys)
            path = self.path_for("noop", "con1")
            if path.exists():
                path.unlink()
            return super().load(with_con1)

    frames = report_store(Vanishing(store.root), plugins, stream=io.StringIO(), figures=False)  # today: KeyError
    assert frames is not None and store.stored_ids() == {"ref0", "ref1", "ref2", "con0"}


def test_a_file_of_another_schema_counts_as_stored_for_planning_until_the_first_read_sets_it_aside(tmp_path):
    store = stored_pairs(tmp_path / "store")
    pq.write_table(pa.table({"x": [1, 2, 3]}), store.path_for("noop", "ref2"))
    assert store.set_aside_damaged(["ref2"]) == set()  # the frame is whole: planning's check stays cheap
    assert store.read_table(columns=["episode_id"]).num_rows == 4
    assert "ref2" not in store.stored_ids()  # the next run plays it again


# -- 6. links in a store check ---------------------------------------------------------------------------------------
def test_store_check_of_a_store_whose_episodes_folder_is_a_link_says_nothing_was_checked(tmp_path, capsys):
    elsewhere = stored_pairs(tmp_path / "elsewhere")
    root = tmp_path / "store"
    root.mkdir()
    (root / "episodes").symlink_to(elsewhere.episodes_dir, target_is_directory=True)
    assert main(["store", "check", str(root)]) == 1  # today: "0 episode files read: all readable", 0
    out = capsys.readouterr().out
    assert "all readable" not in out and "episodes" in out and "link" in out and "nothing" in out, out


def test_files_set_aside_earlier_are_counted_without_following_a_link(tmp_path, capsys):
    store = stored_pairs(tmp_path / "store")
    outside = tmp_path / "outside.parquet"
    outside.write_bytes(b"someone else's")
    folder = store.root / "damaged" / "episodes" / "noop"
    folder.mkdir(parents=True)
    (folder / "x.parquet").symlink_to(outside)
    assert main(["store", "check", str(store.root)]) == 0
    out = capsys.readouterr().out
    assert "5 episode files read: all readable" in out and "set aside earlier" not in out, out  # today: 1 earlier


# -- 7. what the one lines say ---------------------------------------------------------------------------------------
def test_store_check_says_why_a_file_could_not_be_moved(tmp_path, capsys):
    store = stored_pairs(tmp_path / "store")
    with open(store.path_for("noop", "ref2"), "r+b") as fh:
        fh.truncate(100)
    (store.root / "damaged").write_text("in the way")
    assert main(["store", "check", str(store.root), "--quarantine"]) == 1
    out = capsys.readouterr().out
    lines = lines_naming(out, "could not be moved")  # today: "(1 could not be moved)", no why
    assert lines and all("damaged" in x and ("not a folder" in x or "link" in x or "exists" in x) for x in lines), out


def test_prune_delete_on_a_store_it_cannot_change_says_so_and_never_says_removed(small_disk, capsys):
    import subprocess

    store = EpisodeStore(small_disk)
    store.write(episode("old", config_hash="h1", created_at="2026-11-01T10:00:00+00:00"))
    store.write(episode("new", config_hash="h2", created_at="2026-11-02T10:00:00+00:00"))
    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)  # a store this user may only read
    assert main(["prune", str(small_disk), "--delete"]) == 2  # today: "1 of 2 episodes removed", then a traceback
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Read-only file system" in err and "0 of 1" in err, err
    assert store.stored_ids() == {"old", "new"}


def test_prune_delete_says_removed_with_the_count_it_removed(tmp_path, capsys):
    store = EpisodeStore(tmp_path / "store")
    store.write(episode("old", config_hash="h1", created_at="2026-11-01T10:00:00+00:00"))
    store.write(episode("new", config_hash="h2", created_at="2026-11-02T10:00:00+00:00"))
    assert main(["prune", str(store.root), "--delete"]) == 0
    err = capsys.readouterr().err
    assert "removed 1 of 2 episodes" in err and store.stored_ids() == {"new"}, err


def test_a_merge_of_a_file_with_null_names_and_arrays_is_one_line_without_a_warning(tmp_path, capsys):
    import warnings

    shard = tmp_path / "shard"
    path = shard / "episodes" / "noop" / "e1.parquet"
    path.parent.mkdir(parents=True)
    table = records_to_table([episode("e1")])
    for name in ("policy", "episode_id", "actions"):
        index = table.schema.get_field_index(name)
        table = table.set_column(index, name, pa.nulls(1, table.schema.field(name).type))
    pq.write_table(table, path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["merge", str(tmp_path / "out"), str(shard)]) == 2
    assert [str(w.message) for w in caught] == []  # today: RuntimeWarning: invalid value encountered in cast
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "e1.parquet" in err, err


def test_a_merge_into_a_full_disk_says_so_in_merges_words(small_disk, tmp_path, capsys):
    shard = EpisodeStore(tmp_path / "shard")
    for i in range(8):
        shard.write(big_episode(f"e{i:02d}", seed=i))
    assert main(["merge", str(small_disk), str(shard.root)]) == 3
    [line] = capsys.readouterr().err.strip().splitlines()[-1:]
    assert "run.out" not in line and "merge" in line and "no room left" in line, line  # today: "another run.out"


# -- 5. one name pattern, matched whole ------------------------------------------------------------------------------
def test_a_name_with_a_trailing_newline_is_no_name():
    from conflictbench.core.registry import NAME_PATTERN
    from conflictbench.store import paths

    assert not paths.is_name("abc\n")  # today: True ($ matches before a final newline)
    assert paths.is_name("abc") and paths.NAME is NAME_PATTERN
    assert NAME_PATTERN.fullmatch("abc\n") is None


def test_a_shard_whose_episode_id_ends_in_a_newline_is_refused(tmp_path):
    from conflictbench.store.merge import merge_stores

    shard = tmp_path / "shard"
    path = shard / "episodes" / "noop" / "nl\n.parquet"
    path.parent.mkdir(parents=True)
    pq.write_table(records_to_table([episode("nl\n")]), path)
    with pytest.raises(UserError, match="cannot name a file"):  # today: merged, a newline in the file's name
        merge_stores(EpisodeStore(tmp_path / "out"), [EpisodeStore(shard)])
    assert not list((tmp_path).rglob("*\n*")) or not (tmp_path / "out").exists()


def test_registering_a_policy_name_with_a_trailing_newline_is_refused():
    from conflictbench.core import PluginError
    from conflictbench.core.registry import check_name

    check_name("policy", "pi0", "a plugin")
    with pytest.raises(PluginError, match="not valid"):  # today: accepted ($ matches before a final newline)
        check_name("policy", "pi0\n", "a plugin")
