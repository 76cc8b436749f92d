"""A store is data, never a path (#42): names read from a store's files, and links inside a store, never take a
write or a delete out of it. Every store here is crafted in tmp_path: real Parquet files, real symbolic links."""

from __future__ import annotations

import io
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from testing_support import episode_record

from conflictbench.cli import main
from conflictbench.core import EpisodeRecord, UserError
from conflictbench.store import EpisodeStore, records_to_table
from conflictbench.store.merge import merge_stores
from conflictbench.store.prune import superseded
from conflictbench.tasks.suite.file import load_suite
from conflictbench.view import Selection, build_site


def episode(eid: str, seed: int = 0, **kw) -> EpisodeRecord:
    rng = np.random.default_rng(seed)
    fields = dict(
        policy="pi0", suite="libero_goal", task_id=3, instruction="open the top drawer and put the bowl inside",
        episode_id=eid, steps=4, eef_pos=rng.normal(size=(5, 3)), target_pos=rng.normal(size=(5, 1, 3)),
        target_names=("bowl_1",), actions=rng.normal(size=(4, 7)), raw_actions=rng.normal(size=(4, 7)),
        config_hash="c1", created_at="2026-11-01T10:00:00+00:00",
    )  # fmt: skip
    return episode_record(**{**fields, **kw})


def crafted(path: Path, record: EpisodeRecord) -> Path:
    """``record`` written as one Parquet file at ``path`` whatever its names say: what a stranger's shard can hold."""
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(records_to_table([record]), path)
    return path


def tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


# -- merge: names inside a shard's files ---------------------------------------------------------------------------
def test_a_shard_whose_names_climb_out_of_the_store_is_refused_and_nothing_is_written(tmp_path, capsys):
    victim = crafted(tmp_path / "victim" / "keep.parquet", episode("keep", 7))  # someone else's file
    before = victim.read_bytes()
    out = EpisodeStore(tmp_path / "out")  # a store of earlier runs: one episode kept, one waiting for a replay
    out.write(episode("e0", 0))
    out.write(episode("w0", 0, error="server: gone", error_kind="server"))
    out_before = tree(out.root)
    shard = tmp_path / "shard"
    EpisodeStore(shard).write(episode("e1", 1))
    bad = crafted(shard / "episodes" / "pi0" / "e2.parquet", episode("keep", 2, policy="../../victim"))
    assert main(["merge", str(out.root), str(shard)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(bad) in err and "'../../victim'" in err, err
    assert victim.is_file(), "the merge deleted a file outside its store (copy_in unlinks the replay path)"
    assert victim.read_bytes() == before, "the merge overwrote a file outside its store"
    assert tree(out.root) == out_before  # refused before anything was written
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "shard", "victim"]


@pytest.mark.parametrize(
    "names",
    [
        dict(episode_id="../../../../escape"),
        dict(episode_id="/tmp/absolute"),
        dict(episode_id=".hidden"),
        dict(episode_id=""),
        dict(episode_id="x" * 300),
        dict(policy=".."),
        dict(policy="a/b"),
        dict(policy=None),
    ],
)
def test_each_name_that_cannot_be_one_path_part_is_refused(tmp_path, names):
    shard = tmp_path / "shard"
    crafted(shard / "episodes" / "pi0" / "e1.parquet", episode("e1", 1, **names))
    with pytest.raises(UserError, match="cannot name a file"):
        merge_stores(EpisodeStore(tmp_path / "out"), [EpisodeStore(shard)])
    assert not (tmp_path / "out").exists()


def test_a_file_whose_contents_name_another_episode_than_its_name_is_refused(tmp_path):
    shard = tmp_path / "shard"
    EpisodeStore(shard).write(episode("e1", 1))
    moved = crafted(shard / "episodes" / "pi0" / "e2.parquet", episode("e3", 3))  # renamed, or crafted
    with pytest.raises(UserError) as caught:
        merge_stores(EpisodeStore(tmp_path / "out"), [EpisodeStore(shard)])
    assert str(moved) in str(caught.value) and "e3" in str(caught.value) and "\n" not in str(caught.value)
    assert not (tmp_path / "out").exists()


def test_merge_skips_linked_files_and_folders_of_a_shard_and_says_so(tmp_path, capsys):
    outside = crafted(tmp_path / "elsewhere" / "pi0" / "e9.parquet", episode("e9", 9))
    shard = tmp_path / "shard"
    EpisodeStore(shard).write(episode("e1", 1))
    (shard / "episodes" / "pi0" / "e9.parquet").symlink_to(outside)
    (shard / "episodes" / "noop").symlink_to(outside.parent, target_is_directory=True)
    assert main(["merge", str(tmp_path / "out"), str(shard)]) == 0
    assert EpisodeStore(tmp_path / "out").stored_ids() == {"e1"}
    err = capsys.readouterr().err
    assert "skipped 2 links in" in err and str(shard / "episodes") in err, err


# -- the store's own paths -----------------------------------------------------------------------------------------
def test_the_store_never_writes_or_reads_a_path_an_episode_names(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    with pytest.raises(UserError, match="cannot name a file"):
        store.write(episode("../../outside", 1))
    with pytest.raises(UserError, match="cannot name a file"):
        store.write(episode("e1", 1, policy="../.."))
    assert not list(tmp_path.rglob("*.parquet"))
    crafted(tmp_path / "secret.parquet", episode("secret", 5))
    with pytest.raises(UserError, match="cannot name a file"):
        store.load([("../../secret", "pi0")])


def test_a_folder_of_the_store_linked_elsewhere_takes_no_write(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    store.write(episode("e1", 1))
    (tmp_path / "elsewhere").mkdir()
    (store.episodes_dir / "noop").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    with pytest.raises(UserError, match="out of the store"):
        store.write(episode("e2", 2, policy="noop"))
    assert list((tmp_path / "elsewhere").iterdir()) == []


# -- prune ---------------------------------------------------------------------------------------------------------
def test_prune_delete_never_reaches_through_a_link_in_the_store(tmp_path, capsys):
    store = EpisodeStore(tmp_path / "store")
    store.write(episode("new", 1, config_hash="h2", created_at="2026-11-02T10:00:00+00:00"))
    store.write(episode("old", 1, config_hash="h1"))
    # someone else's folder, holding an older identity of the same episode, linked into the store
    other = crafted(tmp_path / "other" / "older.parquet", episode("older", 1, config_hash="h0", created_at="2026"))
    (store.episodes_dir / "mine").symlink_to(other.parent, target_is_directory=True)
    assert main(["prune", str(store.root), "--delete"]) == 0
    err = capsys.readouterr().err
    assert other.is_file(), "prune deleted a file outside the store through a link"
    assert store.stored_ids() == {"new"}
    assert "skipped 1 link in" in err and "removed 1 of 2 episodes" in err, err


def test_unlink_inside_never_follows_a_linked_folder_and_removes_a_link_itself(tmp_path):
    from conflictbench.store import paths

    root, other = tmp_path / "root", tmp_path / "other"
    (root / "a").mkdir(parents=True)
    other.mkdir()
    (other / "f").write_text("keep")
    (root / "b").symlink_to(other, target_is_directory=True)
    with pytest.raises(UserError, match="is a link"):
        paths.unlink_inside(root, root / "b" / "f")
    assert (other / "f").read_text() == "keep"
    (root / "a" / "l").symlink_to(other / "f")
    assert paths.unlink_inside(root, root / "a" / "l") is True  # the link goes, never what it names
    assert (other / "f").read_text() == "keep" and not os.path.lexists(root / "a" / "l")
    assert paths.unlink_inside(root, root / "a" / "gone") is False
    with pytest.raises(UserError, match="out of"):
        paths.unlink_inside(root, root / ".." / "other" / "f")
    assert (other / "f").read_text() == "keep"


def test_inside_is_decided_after_resolution(tmp_path):
    from conflictbench.store import paths

    (tmp_path / "root" / "a").mkdir(parents=True)
    (tmp_path / "root" / "up").symlink_to(tmp_path, target_is_directory=True)
    assert paths.inside(tmp_path / "root", tmp_path / "root" / "a" / "new.parquet")
    assert not paths.inside(tmp_path / "root", tmp_path / "root" / "up" / "x")
    assert not paths.inside(tmp_path / "root", tmp_path / "root" / ".." / "x")
    assert not paths.inside(tmp_path / "root", tmp_path / "root-sibling" / "x")  # a prefix is not a parent


# -- view ----------------------------------------------------------------------------------------------------------
@pytest.fixture
def paired(tmp_path) -> EpisodeStore:
    """A store of one pair (a reference and a conflict episode of a shipped case)."""
    case = next(c for c in load_suite().cases if (c.suite, c.task_id) == ("libero_goal", 3))
    store = EpisodeStore(tmp_path / "results")
    store.write(episode("ref", 1, policy="noop"))
    store.write(episode("con", 2, policy="noop", case_id=case.case_id, family=case.family, level=case.level,
                        instruction=case.instruction))  # fmt: skip
    return store


def test_the_viewer_never_writes_or_deletes_through_a_link_in_its_site(paired, tmp_path, capsys):
    other = tmp_path / "other-site"
    other.mkdir()
    (other / "keep.html").write_text("someone else's page")
    (paired.root / "view").mkdir()
    (paired.root / "view" / "pairs").symlink_to(other, target_is_directory=True)
    assert main(["view", str(paired.root), "--videos", "0", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert (other / "keep.html").read_text() == "someone else's page"
    assert sorted(p.name for p in other.iterdir()) == ["keep.html"]
    assert "error:" in err and str(paired.root / "view" / "pairs") in err and "link" in err, err
    assert len(err.strip().splitlines()) == 1 or "conflictbench view:" in err.splitlines()[0]


def test_a_store_that_is_itself_a_link_at_view_is_refused(paired, tmp_path):
    (tmp_path / "other-site").mkdir()
    (paired.root / "view").symlink_to(tmp_path / "other-site", target_is_directory=True)
    assert main(["view", str(paired.root), "--videos", "0", "--no-progress"]) == 2
    assert list((tmp_path / "other-site").iterdir()) == []


def test_the_viewer_writes_no_page_an_episode_id_names_out_of_its_site(paired, tmp_path, plugins, capsys):
    """A file whose id is not the one its place names is not read as an episode at all (#42): set aside, named."""
    con = paired.records(["con"])[0]
    crafted(paired.episodes_dir / "noop" / "con.parquet", replace(con, episode_id="../../../escaped"))
    built = build_site(paired.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    assert built.pairs == 0 and not list(tmp_path.rglob("escaped*"))
    [line] = [x for x in capsys.readouterr().err.splitlines() if "con.parquet" in x]
    assert "not the one its place names" in line and (paired.root / "damaged" / "episodes" / "noop").is_dir()


def test_the_viewer_skips_linked_pages_when_clearing_stale_ones(paired, tmp_path, plugins):
    site = tmp_path / "site"
    build_site(paired.root, site, plugins, Selection(), videos=0, progress=False)
    keep = tmp_path / "keep.html"
    keep.write_text("someone else's page")
    (site / "pairs" / "stale.html").symlink_to(keep)  # a stale page that is a link: the link goes, not its target
    build_site(paired.root, site, plugins, Selection(), videos=0, progress=False)
    assert keep.read_text() == "someone else's page"
    assert sorted(p.name for p in (site / "pairs").iterdir()) == ["con.html"]


def test_prune_refuses_a_folder_turned_into_a_link_after_it_was_listed(tmp_path):
    from conflictbench.store.prune import remove

    store = EpisodeStore(tmp_path / "store")
    store.write(episode("new", 1, config_hash="h2", created_at="2026-11-02T10:00:00+00:00"))
    store.write(episode("old", 1, config_hash="h1"))
    listed = superseded(store)
    assert [s.episode_id for s in listed] == ["old"]
    other = crafted(tmp_path / "other" / "old.parquet", episode("old", 1))  # a file of the same name elsewhere
    (store.episodes_dir / "pi0").rename(tmp_path / "moved")
    (store.episodes_dir / "pi0").symlink_to(other.parent, target_is_directory=True)
    with pytest.raises(UserError, match="is a link"):
        remove(store, listed)
    assert other.is_file()


def test_a_video_is_never_written_through_a_link_left_at_its_temporary_name(tmp_path):
    pytest.importorskip("av")
    from conflictbench.view.video import Mp4Sink

    target = tmp_path / "victim.txt"
    target.write_text("keep")
    sink = Mp4Sink(str(tmp_path / "videos" / "e1.mp4"), fps=10)
    (tmp_path / "videos").mkdir()
    sink._temporary.symlink_to(target)
    sink.open()
    for _ in range(3):
        sink.add(np.zeros((16, 16, 3), dtype=np.uint8))
    assert sink.close() > 0
    assert target.read_text() == "keep" and not (tmp_path / "videos" / "e1.mp4").is_symlink()


# -- reports written into a store ----------------------------------------------------------------------------------
def test_the_report_never_writes_through_a_link_in_the_stores_report_folder(paired, tmp_path, plugins):
    from conflictbench.report import report_store

    victim = tmp_path / "bashrc"
    victim.write_text("keep")
    (paired.root / "report").mkdir()
    (paired.root / "report" / "report.md").symlink_to(victim)
    with pytest.raises(UserError, match="is a link"):
        report_store(paired, plugins, out_dir=paired.root / "report", stream=io.StringIO(), figures=False)
    assert victim.read_text() == "keep"


def test_a_stores_report_folder_that_is_a_link_takes_no_report(paired, tmp_path, plugins):
    from conflictbench.report import report_store

    (tmp_path / "home").mkdir()
    (paired.root / "report").symlink_to(tmp_path / "home", target_is_directory=True)
    with pytest.raises(UserError, match="link inside the store"):
        report_store(paired, plugins, out_dir=paired.root / "report", stream=io.StringIO(), figures=False)
    assert list((tmp_path / "home").iterdir()) == []


def test_reproduce_never_writes_through_a_link_in_the_report_folder(tmp_path, plugins):
    from conflictbench.report.reproduce import write_report

    entry = next(iter(plugins.published_results().values()))
    victim = tmp_path / "bashrc"
    victim.write_text("keep")
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / f"reproduce-{entry.name}.md").symlink_to(victim)
    with pytest.raises(UserError, match="is a link"):
        write_report([], entry, tmp_path / "report")
    assert victim.read_text() == "keep"


def test_prune_deletes_a_file_only_on_what_that_file_itself_holds(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    store.write(episode("cur", 1, config_hash="h2", created_at="2026-11-02T10:00:00+00:00"))  # the current identity
    store.write(episode("old", 1, config_hash="h1"))
    # a file that claims to be "cur", played under an older identity: its row must not condemn the real "cur" (it is
    # not read as an episode at all: set aside as not holding the episode its place names)
    crafted(store.episodes_dir / "pi0" / "fake.parquet", episode("cur", 1, config_hash="h0", created_at="2026-10"))
    assert [s.episode_id for s in superseded(store)] == ["old"]
    assert main(["prune", str(store.root), "--delete"]) == 0
    assert store.stored_ids() == {"cur"} and (store.root / "damaged" / "episodes" / "pi0" / "fake.parquet").is_file()


def test_only_regular_files_are_episodes(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    store.write(episode("e1", 1))
    os.mkfifo(store.episodes_dir / "pi0" / "fifo.parquet")  # reading it would wait for a writer for ever
    (store.episodes_dir / "pi0" / "folder.parquet").mkdir()
    assert [p.name for p in store.files()] == ["e1.parquet"] and store.stored_ids() == {"e1"}
