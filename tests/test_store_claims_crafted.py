"""Crafted entries in a store's ``claims/`` and temporaries (#42, after review): a claim is data someone else may
have written, so its process id is bounded before it reaches ``os.kill``, and only a regular file is read as a claim
(a FIFO would block the reader, a folder cannot be read). Real files, FIFOs and folders in tmp_path."""

from __future__ import annotations

import os
import socket
import threading

import pytest
from test_store_claims import claim_text

from conflictbench.core import UserError
from conflictbench.store import EpisodeStore
from conflictbench.store.claims import pid_alive, pid_place, read_claim


def claims_store(tmp_path) -> EpisodeStore:
    store = EpisodeStore(tmp_path / "store")
    store.claims_dir.mkdir(parents=True)
    return store


@pytest.mark.parametrize("pid", [0, 2**22 + 1, 99999999999999999999999])
def test_a_claim_of_a_pid_no_process_can_have_is_taken_over(tmp_path, pid):
    store = claims_store(tmp_path)
    (store.claims_dir / "ep1.claim").write_text(claim_text(socket.gethostname(), pid, "0123456789ab", pid_place()))
    assert store.claim("ep1")  # today: OverflowError (os.kill); pid 0 read alive (it signals this process group)
    assert store._owns(store.claims_dir / "ep1.claim")


def test_pids_out_of_range_are_never_alive():
    assert not pid_alive(0) and not pid_alive(-1) and not pid_alive(2**22) and not pid_alive(10**23)
    assert pid_alive(os.getpid())


def test_a_temporary_naming_a_pid_no_process_can_have_is_stale_and_cleaned(tmp_path):
    store = EpisodeStore(tmp_path / "store")
    folder = store.episodes_dir / "noop"
    folder.mkdir(parents=True)
    name = f".e1.parquet.99999999999999999999999-0123456789ab@{socket.gethostname()}~{pid_place()}.tmp"
    (folder / name).write_bytes(b"half")
    assert store.clean_stale_temporaries() == 1  # today: OverflowError
    assert not (folder / name).exists()


def test_a_fifo_at_a_claims_place_never_blocks_and_is_taken_over(tmp_path):
    store = claims_store(tmp_path)
    os.mkfifo(store.claims_dir / "ep1.claim")
    outcome: list[object] = []
    worker = threading.Thread(target=lambda: outcome.append(store.claim("ep1")), daemon=True)
    worker.start()
    worker.join(timeout=10)
    if worker.is_alive():  # today: blocked in open() for a writer; unblock it so the test process can end
        with open(store.claims_dir / "ep1.claim", "w"):
            pass
        worker.join(timeout=10)
        pytest.fail("reading a FIFO at a claim's place blocked the run")
    assert outcome == [True] and (store.claims_dir / "ep1.claim").is_file()
    assert read_claim(store.claims_dir / "ep1.claim") is not None


def test_a_folder_at_a_claims_place_is_refused_in_one_line(tmp_path):
    store = claims_store(tmp_path)
    (store.claims_dir / "ep1.claim").mkdir()
    with pytest.raises(UserError) as caught:  # today: IsADirectoryError
        store.claim("ep1")
    message = str(caught.value)
    assert "ep1.claim" in message and "not a file" in message and "\n" not in message
    assert not store.held_by_others(["ep1"])
