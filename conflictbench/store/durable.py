"""Writing into a store so that what is acknowledged stays, and what fails leaves nothing behind.

Every file of a store is written aside and renamed into place; here are the two things around that: a failed
write removes its temporary and turns a file system that takes no more into one line (:func:`stops_when_full`), and
a rename is made durable by syncing its folder (:func:`sync_folder`). :func:`land` does all of it without following a
link below the store's root (#42).
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from conflictbench.core import StoreFull

from . import paths

#: What a file system says when it takes no more: full, over a quota, past a file size limit.
NO_ROOM = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


@contextlib.contextmanager
def stops_when_full(root: Path, temporary: Path | None = None) -> Iterator[None]:
    """Around a write into the store: where it fails (an interrupt too), its ``temporary`` is removed, so no later
    run meets half a file; where the file system takes no more, the failure is :class:`StoreFull`, one line."""
    try:
        yield
    except BaseException as exc:
        if temporary is not None:
            with contextlib.suppress(OSError):
                temporary.unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.errno in NO_ROOM:
            raise StoreFull(str(root), os.strerror(exc.errno)) from None
        raise


def land(root: Path, final: Path, tag: str, write: Callable[[BinaryIO], object]) -> None:
    """``write(file)`` into a temporary beside ``final`` (``.<name>.<tag>.tmp``, created exclusively, never through a
    link), flushed to disk, renamed into place, and the folder synced: whole or absent, and once returned, there
    after a power loss. The folders are made or entered from ``root`` without following a link (one that is a link
    is refused in one line); a failed write leaves no temporary; a full disk is :class:`StoreFull`."""
    *folders, name = Path(os.path.abspath(final)).relative_to(os.path.abspath(root)).parts
    with stops_when_full(root):
        fd = paths.open_folder(root, folders, "an episode", make=True)
        if fd is None:
            raise FileNotFoundError(errno.ENOENT, "vanished while written", str(final.parent))
        try:
            paths.write_at(fd, name, write, tag=tag, sync=True)
            _sync(fd)
        finally:
            os.close(fd)


def sync_folder(folder: Path) -> None:
    """Flush a folder's entries: a file renamed into it survives a power loss only once its folder is synced."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        _sync(fd)
    finally:
        os.close(fd)


def _sync(fd: int) -> None:
    try:
        os.fsync(fd)
    except OSError as exc:
        if exc.errno not in (errno.EINVAL, errno.ENOTSUP):  # a file system that cannot sync a folder has no need
            raise
