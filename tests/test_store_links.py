"""Every write and delete in a store stays in it (#42, section 4): set-aside damaged files, episodes' temporaries,
markers, claims, stale temporaries and the run's server logs never go through a link someone left in the store.
Every store here is real (Parquet files, symbolic links in tmp_path); each link points at a folder or file outside
the store whose contents must be unchanged after."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from testing_support import episode_record

from conflictbench.core import UserError
from conflictbench.store import EpisodeStore


def episode(eid: str, seed: int = 0, **kw):
    rng = np.random.default_rng(seed)
    fields = dict(
        policy="noop", suite="libero_goal", task_id=3, instruction="open the drawer", episode_id=eid, steps=4,
        eef_pos=rng.normal(size=(5, 3)), target_pos=rng.normal(size=(5, 1, 3)), target_names=("bowl_1",),
        actions=rng.normal(size=(4, 7)), raw_actions=rng.normal(size=(4, 7)), config_hash="h",
    )  # fmt: skip
    return episode_record(**{**fields, **kw})


def outside(tmp_path: Path) -> Path:
    """A folder beside the store, holding one file a link must never reach."""
    folder = tmp_path / "elsewhere"
    folder.mkdir()
    (folder / "keep.txt").write_text("keep")
    return folder


def untouched(folder: Path) -> bool:
    return sorted(p.name for p in folder.iterdir()) == ["keep.txt"] and (folder / "keep.txt").read_text() == "keep"


def truncated(store: EpisodeStore, eid: str) -> Path:
    path = store.write(episode(eid))
    path.write_bytes(path.read_bytes()[:100])
    return path


# -- 1. setting a damaged file aside ---------------------------------------------------------------------------------


def test_a_linked_damaged_folder_takes_no_set_aside_file(tmp_path, capsys):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    path = truncated(store, "a")
    (store.root / "damaged").symlink_to(elsewhere, target_is_directory=True)
    table = store.read_table(columns=["episode_id"])
    assert table.num_rows == 0
    assert untouched(elsewhere)  # today: elsewhere/episodes/noop/a.parquet and its note
    assert path.exists()  # left where it was: each read skips it again
    [line] = [x for x in capsys.readouterr().err.splitlines() if "a.parquet" in x]
    assert "cannot set it aside" in line and "link" in line


def test_a_linked_folder_below_damaged_takes_no_set_aside_file(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    path = truncated(store, "a")
    (store.root / "damaged" / "episodes").mkdir(parents=True)
    (store.root / "damaged" / "episodes" / "noop").symlink_to(elsewhere, target_is_directory=True)
    store.read_table(columns=["episode_id"])
    assert untouched(elsewhere) and path.exists()


def test_a_link_at_the_notes_place_is_replaced_never_written_through(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    truncated(store, "a")
    folder = store.root / "damaged" / "episodes" / "noop"
    folder.mkdir(parents=True)
    (folder / "a.parquet.why").symlink_to(elsewhere / "keep.txt")
    store.read_table(columns=["episode_id"])
    assert untouched(elsewhere)  # today: keep.txt holds the note
    assert (folder / "a.parquet").is_file() and not (folder / "a.parquet.why").is_symlink()
    assert "magic" in (folder / "a.parquet.why").read_text().lower()


# -- 2. episodes, markers, claims, temporaries -----------------------------------------------------------------------


def temporary_name(store: EpisodeStore, name: str) -> str:
    return f".{name}.{store._temporary_tag}.tmp"


def test_an_episode_is_never_written_through_a_link_at_its_temporary_name(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    folder = store.episodes_dir / "noop"
    folder.mkdir(parents=True)
    (folder / temporary_name(store, "a.parquet")).symlink_to(elsewhere / "keep.txt")
    path = store.write(episode("a"))
    assert untouched(elsewhere)  # today: keep.txt became the episode's Parquet file
    assert pq.read_table(path).num_rows == 1 and not path.is_symlink()


def test_a_linked_policy_folder_takes_no_episode(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    store.episodes_dir.mkdir(parents=True)
    (store.episodes_dir / "noop").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(UserError, match="link"):
        store.write(episode("a"))
    assert untouched(elsewhere)


def test_the_failed_twice_marker_is_never_written_through_a_link(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    failed = episode("a", error="server gone", error_kind="server")
    store.write(failed)
    marker = store.replay_dir / "noop" / "a.failed-twice"
    marker.symlink_to(elsewhere / "keep.txt")
    os.utime(elsewhere / "keep.txt", (0, 0))
    store.write(failed)  # the same failure again: the marker is made
    assert (elsewhere / "keep.txt").stat().st_mtime == 0  # today: touched through the link
    assert marker.is_file() and not marker.is_symlink()
    assert store.repeated_failure_ids() == {"a"}


def test_a_linked_claims_folder_takes_no_claim_and_no_lock(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    store.root.mkdir()
    store.claims_dir.symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(UserError, match="claims.*link"):
        store.claim("a")
    assert untouched(elsewhere)  # today: elsewhere/a.claim


def test_a_link_at_the_takeover_lock_is_refused_in_one_line(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    store.claims_dir.mkdir(parents=True)
    (store.claims_dir / "a.claim").write_text("another-machine 1 t\n")
    (store.claims_dir / ".takeover.lock").symlink_to(elsewhere / "keep.txt")
    os.utime(elsewhere / "keep.txt", (0, 0))
    with pytest.raises(UserError, match="takeover.lock"):
        store.claim("a")
    assert untouched(elsewhere) and (elsewhere / "keep.txt").stat().st_mtime == 0


def test_a_claim_is_never_written_through_a_link_at_its_temporary_name(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    store.claims_dir.mkdir(parents=True)
    (store.claims_dir / temporary_name(store, "a")).symlink_to(elsewhere / "keep.txt")
    assert store.claim("a")
    assert untouched(elsewhere)  # today: keep.txt holds the claim's text
    assert store.refresh_claims(["a"]) == set() and untouched(elsewhere)
    store.release("a")
    assert not (store.claims_dir / "a.claim").exists()


def test_cleaning_stale_temporaries_never_reaches_through_a_linked_folder(tmp_path):
    elsewhere = outside(tmp_path)
    stale = f".x.parquet.999999999-0123456789ab@{os.uname().nodename}.tmp"  # a dead pid of this host, older tag
    (elsewhere / stale).write_text("someone else's")
    store = EpisodeStore(tmp_path / "store")
    store.episodes_dir.mkdir(parents=True)
    (store.episodes_dir / "noop").symlink_to(elsewhere, target_is_directory=True)
    assert store.clean_stale_temporaries() == 0
    assert (elsewhere / stale).exists()  # today: deleted through the link


def test_a_linked_code_folder_takes_no_manifest(tmp_path):
    from conflictbench.sim.identity_change import keep_manifests

    elsewhere = outside(tmp_path)
    root = tmp_path / "store"
    root.mkdir()
    (root / "code").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(UserError, match="code.*link"):
        keep_manifests(root, {"pkg==1.0 files=abc": {"a.py": "0"}})
    assert untouched(elsewhere)  # today: elsewhere/pkg-1.0-abc.json


# -- 3. the run's server logs ----------------------------------------------------------------------------------------


def test_a_servers_log_is_never_written_through_a_link(tmp_path):
    from conflictbench.hosting import ServerProcess

    elsewhere = outside(tmp_path)
    logs = tmp_path / "logs"
    logs.mkdir()
    server = ServerProcess([sys.executable, "-c", "print('hello from the server')"], name="t", ready=lambda: True,
                           startup_timeout_s=10, log_dir=logs)  # fmt: skip
    server.log_path.symlink_to(elsewhere / "keep.txt")
    try:
        with pytest.raises(UserError, match="link"):
            server.start()
    finally:
        server.stop()
    assert untouched(elsewhere)  # today: keep.txt got the server's output appended


def test_the_stores_server_log_folder_is_refused_where_it_leads_out(tmp_path):
    elsewhere = outside(tmp_path)
    store = EpisodeStore(tmp_path / "store")
    store.root.mkdir()
    (store.root / "logs").symlink_to(elsewhere, target_is_directory=True)
    with pytest.raises(UserError, match="logs.*leads out"):
        store.server_log_dir()
    (store.root / "logs").unlink()
    assert store.server_log_dir() == store.root / "logs" / "servers"
