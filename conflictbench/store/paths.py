"""A store is data, never a path (#42): the helpers every writer and deleter of a store, a merge and a site uses.

A store's root is the user's choice (``run.out``, a command's DIR or ``--out``) and is trusted, a link included.
Everything below it is data someone else may have written: a shard copied from another machine, a store shared on
a network file system, a site folder. So

- a name read from a file (a policy, an episode id) becomes a path part only if it is one plain name
  (:func:`check_name`: the registry's name pattern, no separators, no leading dot, bounded length);
- a path written or deleted must stay under its root after resolution (:func:`inside`, :func:`confined`);
- nothing that deletes follows a link (:func:`unlink_inside` walks from the root with ``O_NOFOLLOW`` and
  removes a link itself, never what it names);
- reading a store skips linked files and folders (:func:`listing`) and says so once (:func:`say_skipped`).
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import BinaryIO

from conflictbench.core import UserError
from conflictbench.core.registry import NAME_PATTERN
from conflictbench.core.words import counted

#: The registry's name pattern, the same object: policies are registered under it, and episode ids (hex digests)
#: match it too. No separator, no leading dot, so never ``..``, a hidden file or a path; matched whole.
NAME = NAME_PATTERN
#: Longer names are refused: with a suffix and a temporary file's tag they must still fit a file name (255 bytes).
MAX_NAME = 128
RULE = f"letters, digits, '_', '.', '-', starting with a letter or digit, at most {MAX_NAME} characters"


def is_name(name: object) -> bool:
    return isinstance(name, str) and len(name) <= MAX_NAME and NAME.fullmatch(name) is not None


def check_name(what: str, name: object, where: str = "") -> str:
    """``name`` if it can be one path part, else a :class:`UserError` saying ``where`` it came from and why."""
    if not is_name(name):
        shown = repr(name) if not isinstance(name, str) or len(name) <= 2 * MAX_NAME else repr(name[:60]) + "..."
        raise UserError(f"{where}{what} {shown} cannot name a file ({RULE}): a store's contents are never paths")
    return name  # type: ignore[return-value]


def inside(root: str | os.PathLike, path: str | os.PathLike) -> bool:
    """Whether ``path``, every link and ``..`` resolved, is ``root`` (resolved) or under it."""
    return Path(path).resolve().is_relative_to(Path(root).resolve())


def confined(root: str | os.PathLike, path: Path, what: str = "the store") -> Path:
    """``path`` if :func:`inside` ``root``, else one line saying it leads out."""
    if not inside(root, path):
        raise UserError(f"{path} leads out of {what} {root} (through a link or '..'): nothing is written there")
    return path


def _relative(root: Path, path: Path, what: str) -> tuple[str, ...]:
    """``path``'s parts below ``root``, ``..`` taken lexically (the walk that follows never crosses a link)."""
    try:
        parts = Path(os.path.abspath(path)).relative_to(os.path.abspath(root)).parts
    except ValueError:
        raise UserError(f"{path} leads out of {what} {root}: nothing is deleted there") from None
    if not parts:
        raise UserError(f"{path} is {what} itself, not a file in it")
    return parts


def open_folder(root: Path, parts: Iterable[str], what: str, make: bool = False) -> int | None:
    """A descriptor of the folder ``root/parts``, reached without following any link below ``root`` (each part made
    first where ``make``); None where a part is missing. A part that is a link (or not a folder) is refused."""
    if make:
        Path(root).mkdir(parents=True, exist_ok=True)  # the root is the user's choice, a link included
    fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
    here = Path(root)
    try:
        for part in parts:
            here = here / part
            if make:
                try:
                    os.mkdir(part, dir_fd=fd)
                except FileExistsError:
                    pass
            try:
                below = os.open(part, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW, dir_fd=fd)
            except FileNotFoundError:
                return None
            except OSError as exc:
                if exc.errno in (errno.ELOOP, errno.ENOTDIR):
                    raise UserError(f"{here} is a link or not a folder: {what} is never followed out of it") from None
                raise
            os.close(fd)
            fd = below
        fd, done = -1, fd
        return done
    finally:
        if fd >= 0:
            os.close(fd)


def unlink_inside(root: str | os.PathLike, path: str | os.PathLike, what: str = "the store") -> bool:
    """Remove the file ``path`` under ``root`` without following a link: a linked folder on the way is refused in
    one line, and a link at ``path`` is removed itself, never what it names. False where it was not there."""
    root, path = Path(root), Path(path)
    *folders, name = _relative(root, path, what)
    fd = open_folder(root, folders, what)
    if fd is None:
        return False
    try:
        os.unlink(name, dir_fd=fd)
    except FileNotFoundError:
        return False
    finally:
        os.close(fd)
    return True


def write_inside(root: str | os.PathLike, path: str | os.PathLike, data: bytes, what: str = "the site") -> None:
    """Write ``path`` under ``root`` whole (a temporary file renamed into place), its folders made or entered
    without following a link: a link on the way is refused in one line; a link at ``path`` is replaced by the file,
    never written through."""
    root, path = Path(root), Path(path)
    *folders, name = _relative(root, path, what)
    fd = open_folder(root, folders, what, make=True)
    if fd is None:
        raise UserError(f"{path.parent} vanished while {what} was written")
    try:
        write_at(fd, name, data)
    finally:
        os.close(fd)


def create_at(folder: int, name: str) -> int:
    """A new file ``name`` in the folder ``folder`` (a descriptor), open for writing: whatever sat at that name
    before (a link someone left at a guessable temporary's name, a file of a dead writer) is removed first, and the
    file is created exclusively and never through a link (``O_EXCL | O_NOFOLLOW``)."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(name, dir_fd=folder)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
    return os.open(name, flags, 0o644, dir_fd=folder)


def write_at(
    folder: int, name: str, data: bytes | Callable[[BinaryIO], object], *, tag: str | None = None, sync: bool = False
) -> None:
    """Write ``name`` in the folder ``folder`` (a descriptor) whole: ``data`` (or what ``data(file)`` writes) goes
    to ``.<name>.<tag>.tmp`` (:func:`create_at`), flushed to disk where ``sync``, then renamed over ``name`` (a link
    there is replaced, never followed). A failed write removes its temporary."""
    temporary = f".{name}.{tag or os.getpid()}.tmp"
    try:
        with os.fdopen(create_at(folder, temporary), "wb") as fh:
            data(fh) if callable(data) else fh.write(data)
            if sync:
                fh.flush()
                os.fsync(fh.fileno())
        os.replace(temporary, name, src_dir_fd=folder, dst_dir_fd=folder)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary, dir_fd=folder)
        raise


def is_store(root: str | os.PathLike) -> bool:
    """Whether ``root`` is an episode store: it has an ``episodes/`` or ``replay/`` folder (one that is a link
    included: what reads it then says it is not followed)."""
    return any((Path(root) / name).is_dir() for name in ("episodes", "replay"))


def writable_folder(folder: Path, what: str) -> Path:
    """``folder``, about to take files of ``what`` (a report: written, never deleted), refused in one line where a
    write there would go through a link: an entry that is a link (``report.md -> ~/.bashrc``), or the folder itself
    when it is a link inside an episode store (the store's data: ``DIR/report`` of a store from elsewhere). A folder
    the user named that is a link is the user's choice."""
    if folder.is_symlink() and is_store(folder.parent):
        raise UserError(f"{folder} is a link inside the store: {what} is written in a folder of its own only")
    links = sorted(p for p in folder.iterdir() if p.is_symlink()) if folder.is_dir() else []
    if links:
        raise UserError(f"{links[0]} is a link: {what} never writes through one ({counted(len(links), 'link')} in "
                        f"{folder}/; remove them)")  # fmt: skip
    return folder


def listing(folder: Path, pattern: str) -> tuple[list[Path], set[Path]]:
    """The regular files under ``folder`` matching ``pattern`` (``*/*.parquet``: one name pattern a level), sorted,
    none reached through a link and none a link itself; and the links skipped there. Walked with ``scandir``,
    whose entries say whether they are links without another system call (as fast as ``glob``), never entering
    a link; a FIFO or a device named like an episode is left out too (reading it would hang or never end)."""
    if folder.is_symlink():
        return [], {folder}
    if not folder.is_dir():
        return [], set()
    parts = Path(pattern).parts
    level: list[tuple[tuple[str, ...], str]] = [((), str(folder))]  # (names below folder, path): sorted as Paths are
    links: set[Path] = set()
    for depth, part in enumerate(parts):
        last, found = depth == len(parts) - 1, []
        for names, here in level:
            try:
                entries = list(os.scandir(here))
            except (FileNotFoundError, NotADirectoryError):  # removed meanwhile
                continue
            for entry in entries:
                if not fnmatch.fnmatchcase(entry.name, part):
                    continue
                if entry.is_symlink():
                    links.add(Path(entry.path))
                elif entry.is_file(follow_symlinks=False) if last else entry.is_dir(follow_symlinks=False):
                    found.append(((*names, entry.name), entry.path))
        level = found
    return [Path(path) for _, path in sorted(level)], links


_said: set[tuple[Path, frozenset[Path]]] = set()


def say_skipped(folder: Path, links: set[Path]) -> None:
    """One line, once per process for the same links, naming what a reading of ``folder`` left out."""
    key = (folder, frozenset(links))
    if not links or key in _said:
        return
    _said.add(key)
    first = sorted(links)[0]
    print(
        f"conflictbench: skipped {counted(len(links), 'link')} in {folder}/ (a store is read without following "
        f"links), e.g. {first.name} -> {os.readlink(first) if first.is_symlink() else '?'}",
        file=sys.stderr,
    )
