"""Who holds a claim (``<store>/claims/<episode id>.claim``): the process that wrote it, named so that no other can
pass for it.

A claim reads ``host pid token/nonce/place``: the host name and process id; a new random token at every renewal
(what tells another machine the owner is alive); a random nonce made once per process (:func:`process_nonce`); and
the place where that process id names one process (:func:`pid_place`: this kernel's boot and pid namespace). Two
containers may share a host name and run their jobs under the same process id: the nonce tells their claims and
temporaries apart, and the place says that the other's process cannot be checked from here (it waits as another
machine's does). Claims of the older ``host pid token`` form are still read; an older reader still parses these.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import functools
import hashlib
import os
import stat
import time
import uuid
from collections.abc import Iterable, Iterator
from pathlib import Path

from conflictbench.core import UserError

from . import paths
from .durable import stops_when_full

#: The lock under which claims are taken over (``claims/.takeover.lock``).
LOCK = ".takeover.lock"

_nonce: tuple[int, str] | None = None


def process_nonce() -> str:
    """A random name for this process, made once (and again in a forked child): what tells this process's claims
    and temporaries from those of another container that shares its host name and process id."""
    global _nonce
    if _nonce is None or _nonce[0] != os.getpid():
        _nonce = (os.getpid(), uuid.uuid4().hex[:12])
    return _nonce[1]


@functools.cache
def pid_place() -> str:
    """Where a process id names one process: this kernel's boot and this pid namespace, as a short digest. Two
    containers of one machine share the boot, not the namespace; two machines never share a boot. A process whose
    claim says another place cannot be checked from here, whatever its host name says."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
        namespace = os.stat("/proc/self/ns/pid").st_ino
    except OSError:  # no /proc (not Linux): the host name alone says where
        boot, namespace = "", 0
    return hashlib.sha256(f"{boot}:{namespace}".encode()).hexdigest()[:10]


@functools.cache
def pid_limit() -> int:
    """One more than the largest process id this kernel hands out (``/proc/sys/kernel/pid_max``; Linux's most,
    2**22, where it cannot be read)."""
    try:
        return int(Path("/proc/sys/kernel/pid_max").read_text())
    except (OSError, ValueError):
        return 2**22


def valid_pid(text: str) -> int | None:
    """``text`` as a process id some process could have, else None. A claim or a temporary's name is data someone
    else may have written: 0 (``os.kill(0, 0)`` signals this process's whole group: always "alive"), a number too
    big for ``os.kill`` (OverflowError), or one past the kernel's limit is no process (#42)."""
    if not (text.isascii() and text.isdigit()) or len(text) > 12:
        return None
    pid = int(text)
    return pid if 1 <= pid < pid_limit() else None


class NotAClaim(UserError):
    """Something that is not a regular file (a folder) sits at a claim's place and cannot be taken over."""


def read_claim(path: Path) -> tuple[str, str, str, str | None, str | None] | None:
    """(host, pid, renewal token, nonce, place) of a claim; the older ``host pid token`` form has no nonce or place
    (both None). None where there is no claim, it cannot be read, or it is garbage (no regular file, a pid no
    process can have): a claim nobody holds, taken over by the next job that wants its episode. Opened never
    through a link (its text would come from anywhere) and without waiting (``O_NONBLOCK``: a FIFO at the claim's
    place would block the run until someone writes to it), and read only where it is a regular file (#42)."""
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    try:
        fd = os.open(path, flags)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        host, pid, token = os.read(fd, 4096).decode().split()
    except (OSError, ValueError):
        return None
    finally:
        os.close(fd)
    if valid_pid(pid) is None:
        return None
    renewal, _, rest = token.partition("/")
    nonce, _, place = rest.partition("/")
    return host, pid, renewal, (nonce or None), (place or None)


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` of this place lives; a pid no process can have (:func:`valid_pid`) never does."""
    if not 1 <= pid < pid_limit():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


class Claims:
    """The claims of an :class:`~conflictbench.store.episodes.EpisodeStore` (its ``claims/`` folder): taken, renewed,
    released and checked. Every write and delete there goes through the folder's descriptor, reached from the
    store's root without following a link (a ``claims`` that is a link is refused in one line), and makes its
    files exclusively, never through a link: a claim, its temporary and the takeover lock stay in the store (#42)."""

    root: Path
    claims_dir: Path
    remote_claim_ttl_s: float
    _host: str
    _seen: dict[str, tuple[str, float]]
    _temporary_tag: str

    @contextlib.contextmanager
    def _claims_folder(self, make: bool = True) -> Iterator[int | None]:
        fd = paths.open_folder(self.root, (self.claims_dir.name,), "a claim", make=make)
        try:
            yield fd
        finally:
            if fd is not None:
                os.close(fd)

    @contextlib.contextmanager
    def _takeover_lock(self, folder: int) -> Iterator[None]:
        """The lock under which claims are taken over, renewed and released, one process at a time."""
        try:
            lock = os.open(LOCK, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644,
                           dir_fd=folder)  # fmt: skip
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                where = self.claims_dir / LOCK
                raise UserError(f"{where} is a link: claims never lock through one (remove it)") from None
            raise
        try:
            fcntl.flock(lock, fcntl.LOCK_EX)
            yield
        finally:
            os.close(lock)

    def _claim_path(self, episode_id: str) -> Path:
        return self.claims_dir / f"{episode_id}.claim"

    def _claimed_by_other(self, path: Path) -> bool:
        """Whether a live process other than this one holds the claim at ``path``."""
        claim = read_claim(path)
        if claim is None:
            return False
        host, pid, token, nonce, place = claim
        if host != self._host or (place is not None and place != pid_place()):
            # Another machine's process, or another container's (the same host name, its own process ids), cannot
            # be checked from here: its claim holds while its owner renews it (each renewal writes a new token),
            # and for the TTL after this process sees it stop changing.
            text, now = " ".join(p or "" for p in claim), time.monotonic()
            seen = self._seen.get(path.name)
            if seen is None or seen[0] != text:
                self._seen[path.name] = (text, now)
                return True
            return now - seen[1] < self.remote_claim_ttl_s
        # This place: a claim with this process's id is this process's, or (another nonce) an earlier process's
        # that had the id, gone since; another id is checked.
        return int(pid) != os.getpid() and pid_alive(int(pid))

    def claim(self, episode_id: str) -> bool:
        """Mark an episode as being played by this process; False if another live process holds it.

        A claim appears whole (written aside, then hard-linked into place, which fails if one exists),
        so no process ever reads a half-written claim as a dead one. Taking over a dead process's
        claim happens under a lock, one process at a time."""
        path = self._claim_path(episode_id)
        mine = f".{episode_id}.{self._temporary_tag}.tmp"
        with stops_when_full(self.root), self._claims_folder() as folder:
            assert folder is not None
            try:
                with os.fdopen(paths.create_at(folder, mine), "w") as fh:
                    fh.write(self._claim_text())
                if _link(folder, mine, path.name):
                    return True
                with self._takeover_lock(folder):
                    if self._claimed_by_other(path):
                        return False
                    self._clear(folder, path)  # ours, its owner died (SIGKILL), or garbage: take it over
                    return _link(folder, mine, path.name)  # fails if a fresh claim landed meanwhile
            finally:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(mine, dir_fd=folder)

    def _clear(self, folder: int, path: Path) -> None:
        """Remove what sits at a claim's place before taking it over: a claim, or garbage that is no regular file (a
        FIFO, a link); a folder there is not removed (it may hold anything): refused in one line (#42)."""
        try:
            os.unlink(path.name, dir_fd=folder)
        except FileNotFoundError:
            pass
        except IsADirectoryError:
            raise NotAClaim(f"{path} is a folder, not a file: no claim can be taken there (remove it)") from None

    def _claim_text(self) -> str:
        """``host pid token/nonce/place``: a new token at every renewal is what tells another machine the owner is
        alive; the nonce and place tell this process from another container's with the same host name and pid
        (:func:`process_nonce`, :func:`pid_place`). Three fields, as before: an older reader still parses it."""
        return f"{self._host} {os.getpid()} {uuid.uuid4().hex}/{process_nonce()}/{pid_place()}\n"

    def _owns(self, path: Path) -> bool:
        claim = read_claim(path)
        if claim is None:
            return False
        host, pid, _, nonce, place = claim
        return (host, pid, nonce, place) == (self._host, str(os.getpid()), process_nonce(), pid_place())

    def refresh_claims(self, episode_ids: Iterable[str]) -> set[str]:
        """Renew the time on this process's claims (another machine reads an old one as its owner gone); returns
        those it no longer holds (taken over after this process looked dead: another job plays them now). Under
        the takeover lock, so a claim taken over meanwhile is never overwritten."""
        ids, lost = list(episode_ids), set()
        if not ids:
            return lost
        with stops_when_full(self.root), self._claims_folder() as folder, self._takeover_lock(folder):
            for episode_id in ids:
                path = self._claim_path(episode_id)
                if not self._owns(path):
                    lost.add(episode_id)
                    continue
                paths.write_at(folder, path.name, self._claim_text().encode(), tag=self._temporary_tag)
        return lost

    def release(self, episode_id: str) -> None:
        """Give up this process's claim (one another process took over stays theirs)."""
        path = self._claim_path(episode_id)
        if not path.exists():
            return
        with self._claims_folder(make=False) as folder:
            if folder is None:
                return
            with self._takeover_lock(folder):
                if self._owns(path):
                    with contextlib.suppress(FileNotFoundError):
                        os.unlink(path.name, dir_fd=folder)

    def held_by_others(self, episode_ids: Iterable[str]) -> set[str]:
        return {e for e in episode_ids if self._claimed_by_other(self._claim_path(e))}


def _link(folder: int, source: str, target: str) -> bool:
    """Create ``target`` as a hard link to ``source`` (both in ``folder``), atomically; False if ``target`` exists."""
    try:
        os.link(source, target, src_dir_fd=folder, dst_dir_fd=folder, follow_symlinks=False)
    except FileExistsError:
        return False
    return True
