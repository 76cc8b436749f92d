"""Damaged episode files: found, named in one line, set aside (never deleted), and played again by the next run.

A file cut short (a copy interrupted, a disk that filled under a tool writing in place) or corrupted (a bad sector, a
bad transfer) cannot be read; left in place it would count as stored by name, never be played again, and stop every
read of the store. So:

- planning, which reads names only, checks the planned stored files cheaply (:func:`footer_damage`: the Parquet
  magic at both ends and a footer length that fits the file; 13 µs a file here against 240 µs for reading the footer
  metadata, both measured on 1,000 episode files with a warm cache);
- every read of the store (reports, merge, prune, the viewer: ``EpisodeStore.read_table`` and ``load``) verifies
  page checksums and that each file holds one row, the episode its place names (:func:`read_placed`); a read that
  fails on the whole set reads it again in halves down to the single file (:func:`read_intact`), so only the
  damaged files are left out: each is set aside (:func:`set_aside`) and the read goes on;
- a file whose columns this version cannot cast is not damage (a newer conflictbench wrote it): every command
  meeting it stops in one line naming it (:class:`NotThisVersion`), and nothing moves it;
- ``conflictbench store check DIR`` reads every file whole (:func:`check_file`), every column.

Set aside means moved to ``<store>/damaged/<episodes|replay>/<policy>/<file>`` with a note beside it (``.why``: what
was wrong, where it was, when), where no read of the store looks; nothing is ever deleted. Where it cannot be moved
(a store this user may only read), it stays, and each read skips it again.
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import pyarrow as pa
import pyarrow.dataset as ds

from conflictbench.core import UserError

from . import paths
from .schema import SCHEMA

T = TypeVar("T")

DAMAGED = "damaged"
"""The quarantine folder of a store: ``<store>/damaged/``."""
NOTE_SUFFIX = ".why"
MAGIC = b"PAR1"
#: A file too short to hold both magics and the footer's length is damaged whatever it says.
SMALLEST = 2 * len(MAGIC) + 4


def footer_damage(path: Path) -> str | None:
    """What is wrong with the file's Parquet frame (magic at both ends, a footer length that fits), or None: reads
    12 bytes, so planning can check every planned episode. A file cut short loses its footer and fails here."""
    try:
        with open(path, "rb") as fh:
            size = os.fstat(fh.fileno()).st_size
            if size < SMALLEST:
                return f"{size} bytes, too short for a Parquet file"
            head = fh.read(len(MAGIC))
            fh.seek(size - 8)
            tail = fh.read(8)
    except FileNotFoundError:
        return None  # gone meanwhile (another job's prune): not damage
    if head != MAGIC:
        return "no Parquet magic at the start"
    if tail[4:] != MAGIC:
        return "no Parquet magic at the end (cut short?)"
    footer = struct.unpack("<I", tail[:4])[0]
    if footer + SMALLEST > size:
        return f"a footer of {footer} bytes in a file of {size} (cut short?)"
    return None


def _scan_format(checksums: bool) -> ds.ParquetFileFormat:
    options = ds.ParquetFragmentScanOptions(page_checksum_verification=checksums)
    return ds.ParquetFileFormat(default_fragment_scan_options=options)


def read_files(files: Sequence[Path], columns: Iterable[str] | None = None, checksums: bool = True) -> pa.Table:
    """The files read through the store's schema (a file from before a column was added has it empty), their page
    checksums verified: a byte flipped inside an array's values, headers intact, reads as another number without
    them (#42). Their cost, 5,800 episode files of 78 kB, warm cache: every column 6.9 s without, 9.5 s with (a
    review's measurement); here, on 2 shared cores, best of 3, 7.8 s and 5.8 s (6.6 s with :func:`read_placed`),
    and for a report's key columns 5.3 s and 5.2 s: within this machine's noise, the opening of each file dominates."""
    dataset = ds.dataset([str(f) for f in files], format=_scan_format(checksums), schema=SCHEMA)
    return dataset.to_table(columns=list(columns) if columns is not None else None)


class NotThisVersion(UserError):
    """A file whose columns this version's schema cannot cast (a list where it reads a number): most likely written
    by another, newer conflictbench. Not damage: never set aside (the version that wrote it reads it); every command
    meeting it stops in this one line, naming it."""

    def __init__(self, path: Path, reason: str):
        super().__init__(
            f"{path} is not readable by this version ({reason}): it was likely written by another (newer) "
            "conflictbench version; read the store with that version, or move the file out of the store"
        )
        self.path, self.reason = path, reason


class Misplaced(Exception):
    """Files that do not hold the one episode each one's place names (``<policy>/<episode id>.parquet``)."""


def _unreadable(exc: BaseException) -> bool:
    """Whether a failed read says the file's content is bad (Arrow's ``ArrowInvalid``, and the OSError without an
    errno it raises for a footer or a page it cannot parse or whose checksum fails), not that the system failed (a
    permission, a vanished file, a full disk) nor that this version cannot cast a newer one's columns."""
    return isinstance(exc, pa.ArrowInvalid) or (isinstance(exc, OSError) and exc.errno is None)


def _other_version(exc: BaseException) -> bool:
    """Whether a failed read is a cast this version cannot make (``ArrowNotImplementedError``: "Unsupported cast")."""
    return isinstance(exc, (pa.ArrowNotImplementedError, pa.ArrowTypeError))


def _reason(exc: BaseException, path: Path) -> str:
    """Arrow's message in one short line, without the path (the line names the file already)."""
    text = " ".join(str(exc).split()).replace(f"'{path}'", "").replace(str(path), "")
    text = text.replace("Could not open Parquet input source : ", "")
    text = text.replace(" Either the file is corrupted or this is not a parquet file.", "")
    return text[:160].rstrip(". ") or type(exc).__name__


NAMES = ("policy", "episode_id")


def read_placed(files: Sequence[Path], columns: Iterable[str] | None = None) -> pa.Table:
    """:func:`read_files`, and each file holds one row, the episode its place names: a file of another schema (all
    its rows, nulls where our columns are), a copy of another episode, another policy's episode under this one's
    folder would otherwise be counted, counted twice, or paired by names no file has at their place (#42). Else
    :class:`Misplaced` (for one file, saying what it holds)."""
    columns = list(columns) if columns is not None else None
    extra = [] if columns is None else [c for c in NAMES if c not in columns]
    table = read_files(files, None if columns is None else [*columns, *extra])
    if table.num_rows != len(files):
        raise Misplaced(f"{table.num_rows} rows, not one episode" if len(files) == 1 else "rows")
    held = list(zip(table["policy"].to_pylist(), table["episode_id"].to_pylist(), strict=True))
    if held != [(f.parent.name, f.name[: -len(f.suffix)]) for f in files]:
        if len(files) == 1:
            [(policy, eid)] = held
            raise Misplaced(f"holds episode {eid} of {policy}, not the one its place names")
        raise Misplaced("names")
    return table.drop_columns(extra) if extra else table


def read_intact(
    files: Sequence[Path],
    columns: Iterable[str] | None = None,
    *,
    on_damage: Callable[[Path, str], None] | None = None,
    on_gone: Callable[[Path], None] | None = None,
    placed: bool = True,
) -> list[pa.Table]:
    """``files`` read, as tables in their order, leaving out the damaged ones: read all at once, and where that fails,
    in halves down to the single file (a few reads per damaged file, not one per file); each damaged file (a page
    whose checksum fails included, and where ``placed``, one not holding the episode its place names:
    :func:`read_placed`) is set aside (or given to ``on_damage``). A file gone meanwhile is left out (and given to
    ``on_gone``); one this version cannot cast stops the read in one line (:class:`NotThisVersion`); an error of
    the system (a permission, a full disk) is raised, as it would be for a whole store."""
    columns = list(columns) if columns is not None else None
    if not files:
        return []
    try:
        return [read_placed(files, columns) if placed else read_files(files, columns)]
    except (pa.ArrowException, OSError, Misplaced) as exc:
        if len(files) > 1:
            middle = len(files) // 2
            keep = dict(on_damage=on_damage, on_gone=on_gone, placed=placed)
            return [*read_intact(files[:middle], columns, **keep), *read_intact(files[middle:], columns, **keep)]
        [path] = files
        if not os.path.lexists(path):
            if on_gone is not None:
                on_gone(path)
            return []
        if _other_version(exc):
            raise NotThisVersion(path, _reason(exc, path)) from None
        if not (isinstance(exc, Misplaced) or _unreadable(exc)):
            raise
        (on_damage or set_aside)(path, str(exc) if isinstance(exc, Misplaced) else _reason(exc, path))
        return []


def check_file(path: Path) -> str | None:
    """What is wrong with the file, read whole (every column, page checksums verified where written, one row naming
    the episode its place names), or None. A file this version cannot cast is :class:`NotThisVersion`, not damage."""
    if (damage := footer_damage(path)) is not None:
        return damage
    try:
        read_placed([path])
    except FileNotFoundError:
        return None
    except Misplaced as exc:
        return str(exc)
    except (pa.ArrowException, OSError) as exc:  # here, whatever the reason: the check says what it could not read
        if _other_version(exc):
            raise NotThisVersion(path, _reason(exc, path)) from None
        return _reason(exc, path)
    return None


def _store_root(path: Path) -> Path:
    """The store a file of ``<store>/<episodes|replay>/<policy>/<file>`` belongs to."""
    return path.parents[2]


def set_aside(path: Path, reason: str, *, say: bool = True, then: str = "the next run plays it again") -> Path | None:
    """Move a damaged episode file to ``<store>/damaged/`` (same place below it) with a note why; one line on stderr
    names it. Returns where it went, or None where it could not be moved (it stays; reads skip it again)."""
    moved, why_not = move_aside(path, reason)
    root = _store_root(path)
    if say and moved is not None:
        print(f"conflictbench: damaged episode file {path.relative_to(root)} ({reason}): set aside as "
              f"{moved.relative_to(root)}; {then}", file=sys.stderr)  # fmt: skip
    elif say and why_not is not None:
        print(f"conflictbench: damaged episode file {path.relative_to(root)} ({reason}) left out; cannot set it "
              f"aside: {why_not}", file=sys.stderr)  # fmt: skip
    return moved


def move_aside(path: Path, reason: str) -> tuple[Path | None, str | None]:
    """:func:`set_aside`'s move, silent: (where it went, None), (None, why it could not be moved), or (None, None)
    where another process set it aside first. Both folders are reached from the store's root without following a
    link, and the note is made whole, never through a link at its name: a link in ``damaged/`` takes nothing out
    of the store (#42)."""
    root = _store_root(path)
    where = path.relative_to(root)
    source = target = None
    try:
        source = paths.open_folder(root, where.parts[:-1], "a damaged file")
        if source is None:
            return None, None  # its folder is gone: so is the file
        target = paths.open_folder(root, (DAMAGED, *where.parts[:-1]), "a damaged file", make=True)
        name, number = path.name, 1
        while _exists(name, target):  # set aside before (the same episode damaged again): keep both
            number += 1
            name = f"{path.stem}.{number}{path.suffix}"
        # the same file system: a rename, atomic (a link is moved as a link); never over an entry of damaged/
        os.rename(path.name, name, src_dir_fd=source, dst_dir_fd=target)
        note = (
            f"{reason}\nwas {where}\nset aside {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} by "
            f"{socket.gethostname()} pid {os.getpid()}\n"
        )
        with contextlib.suppress(OSError):  # (a full disk) the file is set aside all the same; the note says why
            paths.write_at(target, name + NOTE_SUFFIX, note.encode())
    except FileNotFoundError:
        if not os.path.lexists(path):
            return None, None  # another process set it aside first
        return None, "a folder is missing"
    except UserError as exc:  # a folder on the way is a link (or a file): never followed
        return None, str(exc)
    except OSError as exc:
        return None, f"{root / DAMAGED}: {exc.strerror or exc}"
    finally:
        for fd in (source, target):
            if fd is not None:
                os.close(fd)
    return root / DAMAGED / where.parent / name, None


def _exists(name: str, folder: int) -> bool:
    try:
        os.stat(name, dir_fd=folder, follow_symlinks=False)
    except FileNotFoundError:
        return False
    return True


class ChosenDamaged(UserError):
    """Episodes a caller chose by their keys turned out damaged where their arrays were read
    (``EpisodeStore.load``): set aside (or left out by that store from then on). A caller that chose them calls
    again (:func:`going_on`); one that does not ends in this one line."""

    def __init__(self, message: str, files: Sequence[Path]):
        super().__init__(message)
        self.files = frozenset(files)


def going_on(call: Callable[[], T]) -> T:
    """``call()``, which chooses episodes by their keys and then reads their arrays; where it meets damage only
    there (:class:`ChosenDamaged`: the file was set aside and named in one line), called again, choosing without
    it as the next command would: the same call goes on. Each try leaves out at least one more file, so this ends;
    a try that meets only files met before ends in the line."""
    met: frozenset[Path] = frozenset()
    while True:
        try:
            return call()
        except ChosenDamaged as exc:
            if exc.files <= met:
                raise
            met |= exc.files


def left_out(path: Path, reason: str) -> None:
    """Name a damaged file a command leaves out without moving it (a merge only reads its shards)."""
    print(
        f"conflictbench: damaged episode file {path} ({reason}) left out; `conflictbench store check --quarantine "
        f"{_store_root(path)}` sets it aside",
        file=sys.stderr,
    )


def set_aside_list(root: Path) -> list[Path]:
    """The files set aside in this store before (notes excluded), listed without following a link (one in
    ``damaged/`` is not a file of this store)."""
    found, _ = paths.listing(Path(root) / DAMAGED, "*/*/*")
    return [p for p in found if not p.name.endswith(NOTE_SUFFIX)]


@dataclass
class CheckResult:
    """What ``store check`` found: files read; the damaged ones (path, why, where set aside or None, why it could
    not be moved or None); those this version cannot read (path, why: never set aside)."""

    read: int = 0
    damaged: list[tuple[Path, str, Path | None, str | None]] = field(default_factory=list)
    other_version: list[tuple[Path, str]] = field(default_factory=list)


def check_files(
    files: Sequence[Path], quarantine: bool, on_file: Callable[[], None] | None = None
) -> CheckResult:  # fmt: skip
    """Read every file whole; with ``quarantine``, set the damaged ones aside (never one of another version)."""
    result = CheckResult()
    for path in files:
        try:
            damage = check_file(path)
        except NotThisVersion as exc:
            result.other_version.append((path, exc.reason))
            damage = None
        result.read += 1
        if damage is not None:
            moved, why_not = move_aside(path, damage) if quarantine else (None, None)
            result.damaged.append((path, damage, moved, why_not))
        if on_file is not None:
            on_file()
    return result
