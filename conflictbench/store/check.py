"""Damaged episode files: found, named in one line, set aside (never deleted), and played again by the next run.

A file cut short (a copy interrupted, a disk that filled under a tool writing in place) or corrupted (a bad sector, a
bad transfer) cannot be read; left in place it would count as stored by name, never be played again, and stop every
read of the store. So:

- planning, which reads names only, checks the planned stored files cheaply (:func:`footer_damage`: the Parquet
  magic at both ends and a footer length that fits the file; 13 µs a file here against 240 µs for reading the footer
  metadata, both measured on 1,000 episode files with a warm cache);
- every read of the store (reports, merge, prune, the viewer: ``EpisodeStore.read_table`` and ``load``) that fails
  on the whole set reads it again in halves down to the single file (:func:`read_intact`), so only the damaged files
  are left out: each is set aside (:func:`set_aside`) and the read goes on;
- ``conflictbench store check DIR`` reads every file whole (:func:`check_file`), page checksums verified.

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


def read_files(files: Sequence[Path], columns: Iterable[str] | None = None, checksums: bool = False) -> pa.Table:
    """The files read through the store's schema (a file from before a column was added has it empty)."""
    dataset = ds.dataset([str(f) for f in files], format=_scan_format(checksums), schema=SCHEMA)
    return dataset.to_table(columns=list(columns) if columns is not None else None)


def _unreadable(exc: BaseException) -> bool:
    """Whether a failed read says the file's content is bad (Arrow's ``ArrowInvalid``, and the OSError without an
    errno it raises for a footer or a page it cannot parse), not that the system failed (a permission, a vanished
    file, a full disk) nor that this version cannot read a newer one's columns (``ArrowNotImplementedError``: never
    set aside, a newer conflictbench reads it)."""
    return isinstance(exc, pa.ArrowInvalid) or (isinstance(exc, OSError) and exc.errno is None)


def _reason(exc: BaseException, path: Path) -> str:
    """Arrow's message in one short line, without the path (the line names the file already)."""
    text = " ".join(str(exc).split()).replace(f"'{path}'", "").replace(str(path), "")
    text = text.replace("Could not open Parquet input source : ", "")
    text = text.replace(" Either the file is corrupted or this is not a parquet file.", "")
    return text[:160].rstrip(". ") or type(exc).__name__


def read_intact(
    files: Sequence[Path], columns: Iterable[str] | None = None, *, on_damage: Callable[[Path, str], None] | None = None
) -> list[pa.Table]:
    """``files`` read, as tables in their order, leaving out the damaged ones: read all at once, and where that fails,
    in halves down to the single file (a few reads per damaged file, not one per file); each damaged file is set
    aside (or given to ``on_damage``). A file gone meanwhile is left out silently; an error of the system (a
    permission, a full disk) is raised, as it would be for a whole store."""
    columns = list(columns) if columns is not None else None
    if not files:
        return []
    try:
        return [read_files(files, columns)]
    except (pa.ArrowException, OSError) as exc:
        if len(files) > 1:
            middle = len(files) // 2
            return [*read_intact(files[:middle], columns, on_damage=on_damage),
                    *read_intact(files[middle:], columns, on_damage=on_damage)]  # fmt: skip
        [path] = files
        if not os.path.lexists(path):
            return []
        if not _unreadable(exc):
            raise
        (on_damage or set_aside)(path, _reason(exc, path))
        return []


def check_file(path: Path) -> str | None:
    """What is wrong with the file, read whole (every column, page checksums verified where written), or None."""
    if (damage := footer_damage(path)) is not None:
        return damage
    try:
        table = read_files([path], checksums=True)
    except FileNotFoundError:
        return None
    except (pa.ArrowException, OSError) as exc:  # here, whatever the reason: the check says what it could not read
        return _reason(exc, path)
    if table.num_rows != 1:
        return f"{table.num_rows} rows, not one episode"
    [row] = table.select(["policy", "episode_id"]).to_pylist()
    if (row["policy"], f"{row['episode_id']}{path.suffix}") != (path.parent.name, path.name):
        return f"holds episode {row['episode_id']} of {row['policy']}, not the one its place names"
    return None


def _store_root(path: Path) -> Path:
    """The store a file of ``<store>/<episodes|replay>/<policy>/<file>`` belongs to."""
    return path.parents[2]


def set_aside(path: Path, reason: str, *, say: bool = True, then: str = "the next run plays it again") -> Path | None:
    """Move a damaged episode file to ``<store>/damaged/`` (same place below it) with a note why; one line on stderr
    names it. Returns where it went, or None where it could not be moved (it stays; reads skip it again). Both
    folders are reached from the store's root without following a link, and the note is made whole, never through
    a link at its name: a link in ``damaged/`` takes nothing out of the store (#42)."""
    root = _store_root(path)
    where = path.relative_to(root)
    source = target = None
    try:
        source = paths.open_folder(root, where.parts[:-1], "a damaged file")
        if source is None:
            return None  # its folder is gone: so is the file
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
            return None  # another process set it aside first
        return _not_moved(where, reason, "a folder is missing", say)
    except UserError as exc:  # a folder on the way is a link (or a file): never followed
        return _not_moved(where, reason, str(exc), say)
    except OSError as exc:
        return _not_moved(where, reason, exc.strerror or str(exc), say)
    finally:
        for fd in (source, target):
            if fd is not None:
                os.close(fd)
    moved = root / DAMAGED / where.parent / name
    if say:
        print(
            f"conflictbench: damaged episode file {where} ({reason}): set aside as {moved.relative_to(root)}; {then}",
            file=sys.stderr,
        )
    return moved


def _exists(name: str, folder: int) -> bool:
    try:
        os.stat(name, dir_fd=folder, follow_symlinks=False)
    except FileNotFoundError:
        return False
    return True


def _not_moved(where: Path, reason: str, why: str, say: bool) -> None:
    if say:
        print(f"conflictbench: damaged episode file {where} ({reason}) left out; cannot set it aside: {why}",
              file=sys.stderr)  # fmt: skip
    return None


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
    """The files set aside in this store before (notes excluded)."""
    folder = Path(root) / DAMAGED
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.glob("*/*/*") if p.is_file() and not p.name.endswith(NOTE_SUFFIX))


@dataclass
class CheckResult:
    """What ``store check`` found: files read, the damaged ones (path, why, where set aside or None)."""

    read: int = 0
    damaged: list[tuple[Path, str, Path | None]] = field(default_factory=list)
    earlier: int = 0
    """Files set aside before this check (``<store>/damaged/``)."""


def check_files(
    files: Sequence[Path], quarantine: bool, on_file: Callable[[], None] | None = None
) -> CheckResult:  # fmt: skip
    """Read every file whole; with ``quarantine``, set the damaged ones aside."""
    result = CheckResult()
    for path in files:
        damage = check_file(path)
        result.read += 1
        if damage is not None:
            moved = set_aside(path, damage, say=False) if quarantine else None
            result.damaged.append((path, damage, moved))
        if on_file is not None:
            on_file()
    return result
