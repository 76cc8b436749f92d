"""Claims between jobs sharing a store, where host names and process ids are not unique (#42, section 5): containers.

Two containers may share a host name (``--hostname``, a pod's name) and run their jobs under the same process id (the
first process of each container's namespace). A claim therefore names its writer by host, pid and something unique
per process (a random nonce made once per process) and per place where a pid means one process (this kernel's boot
and pid namespace); a claim of the older ``host pid token`` form is still read.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import uuid

from conflictbench.store import EpisodeStore
from conflictbench.store.claims import pid_place, process_nonce


def claim_text(host: str, pid: int, nonce: str | None = None, place: str | None = None) -> str:
    token = uuid.uuid4().hex
    if nonce is None:  # the older form
        return f"{host} {pid} {token}\n"
    return f"{host} {pid} {token}/{nonce}/{place}\n"


def dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_a_claim_with_this_host_and_pid_but_another_processs_nonce_is_not_ours(tmp_path):
    """Another container's job, same host name and pid: not ours to renew or release, and never renewed as ours."""
    store = EpisodeStore(tmp_path)
    store.claims_dir.mkdir(parents=True)
    path = store.claims_dir / "ep1.claim"
    text = claim_text(socket.gethostname(), os.getpid(), "0123456789ab", pid_place())
    path.write_text(text)
    assert not store._owns(path)  # today: True (host and pid match)
    assert store.refresh_claims(["ep1"]) == {"ep1"}  # lost: not renewed as ours
    store.release("ep1")
    assert path.read_text() == text  # not released as ours


def test_a_claim_of_another_pid_namespace_with_this_host_name_waits_like_another_machines(tmp_path):
    """Same host name, a pid that means nothing here (another container): its process cannot be checked from here,
    so its claim holds while it is renewed and for the TTL after, as another machine's does; never taken over as
    dead because no process of that id lives in this namespace."""
    store = EpisodeStore(tmp_path)
    store.claims_dir.mkdir(parents=True)
    (store.claims_dir / "ep1.claim").write_text(claim_text(socket.gethostname(), dead_pid(), "0123456789ab", "ffff"))
    assert store.held_by_others(["ep1"]) == {"ep1"}  # today: set() (its pid is not alive here: taken over)
    assert store.claim("ep1") is False
    store.remote_claim_ttl_s = 0.0  # its owner stopped renewing it long enough ago
    assert store.held_by_others(["ep1"]) == set()
    assert store.claim("ep1") is True and store._owns(store.claims_dir / "ep1.claim")


def test_claims_in_the_older_form_are_still_read(tmp_path):
    store = EpisodeStore(tmp_path)
    store.claims_dir.mkdir(parents=True)
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (store.claims_dir / "live.claim").write_text(claim_text(socket.gethostname(), sleeper.pid))
        (store.claims_dir / "dead.claim").write_text(claim_text(socket.gethostname(), dead_pid()))
        (store.claims_dir / "away.claim").write_text(claim_text("another-machine", 12345))
        assert store.held_by_others(["live", "dead", "away"]) == {"live", "away"}
        assert store.claim("dead") is True and store.claim("live") is False
    finally:
        sleeper.kill()
        sleeper.wait()


def test_this_processs_claims_are_its_own_and_say_where_a_pid_means_it(tmp_path):
    store = EpisodeStore(tmp_path)
    assert store.claim("ep1") is True
    path = store.claims_dir / "ep1.claim"
    host, pid, token = path.read_text().split()
    assert (host, pid) == (socket.gethostname(), str(os.getpid()))  # an older reader still parses it
    assert token.split("/")[1:] == [process_nonce(), pid_place()]
    assert store._owns(path) and store.refresh_claims(["ep1"]) == set()
    store.release("ep1")
    assert not path.exists()


def test_a_claim_of_an_earlier_process_with_this_pid_is_taken_over(tmp_path):
    """Same host, same place, same pid, another nonce: its writer was an earlier process of this id, now gone."""
    store = EpisodeStore(tmp_path)
    store.claims_dir.mkdir(parents=True)
    (store.claims_dir / "ep1.claim").write_text(
        claim_text(socket.gethostname(), os.getpid(), "0123456789ab", pid_place())
    )
    assert store.held_by_others(["ep1"]) == set()
    assert store.claim("ep1") is True and store._owns(store.claims_dir / "ep1.claim")


def test_temporaries_of_another_container_with_this_host_and_pid_are_left_alone(tmp_path):
    store = EpisodeStore(tmp_path)
    folder = store.episodes_dir / "noop"
    folder.mkdir(parents=True)
    host, pid = socket.gethostname(), os.getpid()
    theirs = folder / f".a.parquet.{pid}-0123456789ab@{host}~ffffffffff.tmp"  # another container, same host and pid
    mine_before = folder / f".b.parquet.{pid}-0123456789ab@{host}~{pid_place()}.tmp"  # an earlier process, this pid
    dead = folder / f".c.parquet.{dead_pid()}-0123456789ab@{host}~{pid_place()}.tmp"
    older = folder / f".d.parquet.{dead_pid()}@{host}.tmp"  # the older tag
    ours = folder / f".e.parquet.{store._temporary_tag}.tmp"  # this process's, being written
    for tmp in (theirs, mine_before, dead, older, ours):
        tmp.write_bytes(b"half")
    assert store.clean_stale_temporaries() == 3
    assert theirs.exists() and ours.exists()
    assert not mine_before.exists() and not dead.exists() and not older.exists()


def test_a_forked_process_has_a_nonce_of_its_own():
    read, write = os.pipe()
    parent = process_nonce()
    child = os.fork()
    if child == 0:  # pragma: no cover (the child)
        os.write(write, process_nonce().encode())
        os._exit(0)
    os.waitpid(child, 0)
    assert os.read(read, 64).decode() not in ("", parent)
