"""The episode store: one Parquet file per finished episode under ``<root>/episodes/<policy>/``.

Each file is written to a temporary name and renamed into place, so a run killed at any moment
leaves only whole episodes behind. A claim file marks an episode being played, so two jobs
sharing a store (a sweep split over processes) never play the same episode twice.

An episode something other than the policy ended (its ``error_kind`` is not ``policy``: a plugin, a
client, a server, the simulator) is stored under ``<root>/replay/<policy>/`` instead. It is kept for
the record and seen by :meth:`EpisodeStore.files`, ``records()`` and reports (which leave it out of the measures and say
how many), but not by :meth:`EpisodeStore.stored_ids`, so the next run plays it again; the replay,
once stored, removes it. Planning reads only file names, never file contents.
"""

from __future__ import annotations

import os
import shutil
import socket
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

import pyarrow as pa
import pyarrow.parquet as pq

from conflictbench.core import EpisodeRecord, StoreFull, UserError

from . import paths
from .check import ChosenDamaged, footer_damage, read_intact, set_aside
from .claims import Claims, pid_alive, pid_place, process_nonce, valid_pid
from .durable import land
from .schema import SCHEMA, records_to_table, table_to_records

SUFFIX = ".parquet"
#: Beside a waiting replay: its last two attempts failed the same way (see ``EpisodeStore.write``).
REPEATED_SUFFIX = ".failed-twice"
#: How long a claim made on another machine holds once this process sees it stop changing (its process cannot be
#: checked from here): a job the scheduler killed gives its episodes up this long after its last refresh. Measured
#: on this machine's own monotonic clock, never against the other machine's: no clocks need to agree.
REMOTE_CLAIM_TTL_S = 10 * 60
#: How often a running job refreshes the claims of the episodes it is playing (well inside the TTL).
CLAIM_REFRESH_S = 60.0


class EpisodeStore(Claims):
    claim_refresh_s = CLAIM_REFRESH_S
    remote_claim_ttl_s = REMOTE_CLAIM_TTL_S

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self._seen: dict[str, tuple[str, float]] = {}
        """Another machine's claim -> (its text, when this process first saw that text, monotonic)."""
        self.episodes_dir = self.root / "episodes"
        self.replay_dir = self.root / "replay"
        self.claims_dir = self.root / "claims"
        self._host = socket.gethostname()
        self._left_out: set[Path] = set()
        """Damaged files met by :meth:`load` that could not be set aside: left out of every later reading here."""

    # -- writing ---------------------------------------------------------------------------
    def path_for(self, policy: str, episode_id: str) -> Path:
        """Where an episode is kept. Its names come from records (a shard's files, too): each must be one plain
        name, and the path must stay in the store once resolved (a linked folder does not take it out), #42."""
        return self._confined(self.episodes_dir, policy, episode_id)

    def replay_path_for(self, policy: str, episode_id: str) -> Path:
        """Where an episode the serving infrastructure ended waits to be played again."""
        return self._confined(self.replay_dir, policy, episode_id)

    def _confined(self, folder: Path, policy: str, episode_id: str) -> Path:
        path = folder / paths.check_name("policy", policy) / f"{paths.check_name('episode id', episode_id)}{SUFFIX}"
        return paths.confined(self.root, path)

    def _land(self, final: Path, write: Callable[[BinaryIO], object]) -> None:
        """``write(file)`` beside ``final``, flushed, renamed into place, the folder synced (``durable.land``): whole
        or absent, never through a link below the root; a full disk is :class:`StoreFull`."""
        land(self.root, final, self._temporary_tag, write)  # clean_stale_temporaries knows the temporary's name

    def copy_in(self, source: Path, policy: str, episode_id: str) -> None:
        """Store an episode file from another store as it is (``conflictbench merge``), atomically."""
        with open(os.open(source, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC), "rb") as src:  # a listed file
            self._land(self.path_for(policy, episode_id), lambda out: shutil.copyfileobj(src, out, 1 << 20))
        paths.unlink_inside(self.root, self.replay_path_for(policy, episode_id))  # played after all

    def write(self, record: EpisodeRecord) -> Path:
        """Write one episode atomically (temporary file in the same directory, then rename).

        An episode something other than the policy ended waits under ``replay/`` for the next run; when it
        failed exactly as its last attempt did (same kind, same message), a marker beside it says so, and
        runs leave it alone unless told to retry (:meth:`repeated_failure_ids`)."""
        replay = record.infrastructure_failed  # not the model's behaviour: the next run plays it again
        final = (self.replay_path_for if replay else self.path_for)(record.policy, record.episode_id)
        repeated = replay and self._last_failure(final) == (record.failure_kind, record.error)
        # Page checksums: a byte flipped on disk later is found by a full read (`conflictbench store check`).
        self._land(final, lambda out: pq.write_table(records_to_table([record]), out, write_page_checksum=True))
        marker = self.replay_path_for(record.policy, record.episode_id).with_suffix(REPEATED_SUFFIX)
        if repeated:  # made whole, never through a link at its name (as every write below the root, #42)
            paths.write_inside(self.root, marker, b"", "the store")
        else:
            paths.unlink_inside(self.root, marker)
        if not replay:  # the replay of an episode the infrastructure ended: drop the failed attempt
            paths.unlink_inside(self.root, self.replay_path_for(record.policy, record.episode_id))
        return final

    @staticmethod
    def _last_failure(path: Path) -> tuple[str | None, str | None] | None:
        """(kind, error) of the attempt stored at ``path`` (a replay waiting), or ``None``: read as every read of the
        store reads (``check.read_intact``); a damaged one is left for this write to replace, not set aside."""
        if not path.is_file():
            return None
        try:
            tables = read_intact([path], on_damage=lambda _path, _why: None)
        except (OSError, UserError, pa.ArrowException):  # (another version's: replaced by this attempt)
            return None
        if not tables:
            return None
        [record] = table_to_records(tables[0])
        return record.failure_kind, record.error

    def repeated_failure_ids(self) -> set[str]:
        """The episodes waiting for a replay whose last two attempts failed the same way (not the policy's
        failure): playing them again would most likely fail again, so a run skips them unless asked."""
        waiting = self.replay_ids()
        return {p.name[: -len(REPEATED_SUFFIX)] for p in self.replay_dir.glob(f"*/*{REPEATED_SUFFIX}")} & waiting

    def server_log_dir(self) -> Path:
        """Where the servers a run starts log (``logs/servers``): refused in one line where a link takes it out of
        the store, as every other write into it (#42)."""
        return paths.confined(self.root, self.root / "logs" / "servers")

    # -- what is there ---------------------------------------------------------------------
    def _parquet_files(self, folder: Path) -> list[Path]:
        """The episode files of ``folder``; linked files and folders are skipped and said once (#42)."""
        found, links = paths.listing(folder, f"*/*{SUFFIX}")
        paths.say_skipped(folder, links)
        return [p for p in found if not p.name.startswith(".") and p not in self._left_out]

    def kept_files(self) -> list[Path]:
        """The episodes stored for good (not those waiting to be played again)."""
        return self._parquet_files(self.episodes_dir)

    def waiting_files(self) -> list[Path]:
        """The episodes the serving infrastructure ended, waiting to be played again."""
        return self._parquet_files(self.replay_dir)

    def files(self) -> list[Path]:
        """Every stored episode: those kept, then those waiting to be played again."""
        kept = self._parquet_files(self.episodes_dir)
        names = {(p.parent.name, p.name) for p in kept}
        # A replay stored just before its failed attempt was removed leaves both: the kept one counts.
        waiting = [p for p in self._parquet_files(self.replay_dir) if (p.parent.name, p.name) not in names]
        return kept + waiting

    def stored_ids(self) -> set[str]:
        """The episodes a run need not play (those waiting for a replay are not among them)."""
        return {p.name[: -len(SUFFIX)] for p in self._parquet_files(self.episodes_dir)}

    def replay_ids(self) -> set[str]:
        """The episodes the serving infrastructure ended, which the next run plays again."""
        kept = self.stored_ids()
        return {p.name[: -len(SUFFIX)] for p in self._parquet_files(self.replay_dir)} - kept

    def __len__(self) -> int:
        return len(self.files())

    def read_table(self, columns: Iterable[str] | None = None, episode_ids: Iterable[str] | None = None) -> pa.Table:
        """Every stored episode, or only those named (missing ones are skipped). A damaged file is named, set aside
        and left out (``check.read_intact``): the read goes on, and the next run plays that episode again."""
        files = self.files()
        if episode_ids is not None:
            wanted = set(episode_ids)
            files = [f for f in files if f.name[: -len(SUFFIX)] in wanted]
        empty = SCHEMA.empty_table() if columns is None else SCHEMA.empty_table().select(list(columns))
        tables = read_intact(files, columns)
        return pa.concat_tables(tables) if tables else empty

    def load(self, keys: Iterable[tuple[str, str]]) -> list[EpisodeRecord]:
        """The episodes named by (episode_id, policy), read straight from their files. One found damaged here (its
        keys read, its arrays not) is set aside (or, where it cannot be moved, left out of this store's readings
        from now on), named in one line, and :class:`~conflictbench.store.check.ChosenDamaged` raised: its caller
        chose it from the keys, and goes on by choosing again without it (``check.going_on``)."""
        files = [self.path_for(policy, eid) for eid, policy in keys]
        damaged: list[tuple[Path, str, Path | None]] = []
        gone: list[Path] = []

        def aside(path: Path, why: str) -> None:
            self._left_out.add(path)
            damaged.append((path, why, set_aside(path, why, then="left out here; the next run plays it again")))

        tables = read_intact(files, on_damage=aside, on_gone=gone.append)
        if damaged:
            path, why, moved = damaged[0]
            more = f" (and {len(damaged) - 1} more)" if len(damaged) > 1 else ""
            where = f"set aside as {moved.relative_to(self.root)}" if moved is not None else "left in place"
            message = f"episode {path.stem} of {path.parent.name} is damaged ({why}){more}: {where}"
            raise ChosenDamaged(f"{message}; run the same command again: it goes on", [d[0] for d in damaged])
        if gone:  # removed since its keys were read (another job's prune): chosen again, it is not there (#42)
            more = f" (and {len(gone) - 1} more)" if len(gone) > 1 else ""
            message = f"episode {gone[0].stem} of {gone[0].parent.name} was removed while read{more}"
            raise ChosenDamaged(f"{message}; run the same command again: it goes on", gone)
        return table_to_records(pa.concat_tables(tables)) if tables else []

    def set_aside_damaged(self, episode_ids: Iterable[str]) -> set[str]:
        """Of the named episodes, those whose kept file is damaged by its Parquet frame (``check.footer_damage``:
        12 bytes read, cheap enough for every planned episode): each named in one line and set aside. Planning
        calls it, since runs read names only: those episodes are no longer stored and are played again."""
        wanted, damaged = set(episode_ids), set()
        for path in self.kept_files():
            eid = path.name[: -len(SUFFIX)]
            if eid in wanted and (why := footer_damage(path)) is not None:
                set_aside(path, why, then="this run plays it again")
                damaged.add(eid)
        return damaged

    def records(self, episode_ids: Iterable[str] | None = None) -> list[EpisodeRecord]:
        return table_to_records(self.read_table(episode_ids=episode_ids))

    # -- temporaries -----------------------------------------------------------------------
    def clean_stale_temporaries(self) -> int:
        """Remove half-written files left by processes of this machine that died mid-write (another
        machine's, on a shared store, cannot be checked from here and are left alone; so are another container's
        with this host name, by the place in their tag)."""
        removed = 0
        for pattern, folder in (
            ("*/.*.tmp", self.episodes_dir),
            ("*/.*.tmp", self.replay_dir),
            (".*.tmp", self.claims_dir),
        ):
            found, _ = paths.listing(folder, pattern)  # never into a linked folder; a link itself is left alone
            for tmp in found:
                if self._stale(tmp.name[: -len(".tmp")]):
                    removed += paths.unlink_inside(self.root, tmp)
        return removed

    def _stale(self, name: str) -> bool:
        """Whether the temporary ``name`` (less ``.tmp``) was left by a process of this place now gone: its tag is
        ``<pid>-<nonce>@<host>~<place>``, or ``<pid>@<host>`` as written before nonces."""
        rest, _, where = name.rpartition("@")
        host, marked, place = where.partition("~")
        text, _, nonce = rest.rpartition(".")[2].partition("-")
        pid = valid_pid(text)  # a name is data: a pid no process can have is a dead one's (never os.kill'd, #42)
        if host != self._host or not text.isdigit() or (marked and place != pid_place()):
            return False
        if pid == os.getpid():  # this process's while being written; another nonce: an earlier one's, gone
            return not marked or nonce != process_nonce()
        return pid is None or not pid_alive(pid)

    @property
    def _temporary_tag(self) -> str:
        """Names this process's temporary files: ``<pid>-<nonce>@<host>~<place>``."""
        return f"{os.getpid()}-{process_nonce()}@{self._host}~{pid_place()}"


class ClaimKeeper:
    """Renews the claims of the episodes a job is playing every ``store.claim_refresh_s``, from a thread of its own
    (the job's loop may wait on a policy or a restarting worker for longer than a claim lasts). ``lost`` holds the
    episodes whose claims another job took over meanwhile: that job plays them, so this one must not store them."""

    def __init__(self, store: EpisodeStore):
        self.store, self.lost = store, set()
        self._held: set[str] = set()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="conflictbench-claims", daemon=True)

    def __enter__(self) -> ClaimKeeper:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def hold(self, episode_id: str) -> None:
        with self._lock:
            self._held.add(episode_id)

    def drop(self, episode_id: str) -> None:
        with self._lock:
            self._held.discard(episode_id)

    def refresh(self) -> None:
        with self._lock:
            held = sorted(self._held)
        lost = self.store.refresh_claims(held)
        with self._lock:
            self.lost |= lost & self._held

    def _run(self) -> None:
        while not self._stop.wait(self.store.claim_refresh_s):
            try:
                self.refresh()
            except (OSError, StoreFull):  # a network store's hiccup, a full disk: the next round tries again
                pass  # (a disk that stays full stops the run at its next write of an episode)
