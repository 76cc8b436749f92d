"""The code behind a rollout, by content: a digest of the files themselves, not a version string.

A version says little while a package is installed editable (`scripts/setup.sh`): conflictbench stayed 0.2.0 and
every plugin 0.1.0 while their rollout code changed. So each distribution that can change an episode (see
``Plugins.provenance``; with the conflictbench distributions it requires, such as conflictbench-serving for a
plugin's server) is identified by ``name==version`` and a digest of its files as they are on disk: an editable
tree's sources or an installed wheel's files alike. For conflictbench itself only the modules a rollout of this
policy runs count (:mod:`.rollout_code`: the run's loop and workers, the policy's own modules and what the plugins
import of conflictbench, with what they import): editing the suite's operators, the report or the viewer does not
make stored episodes stale, nor does editing one model family's image steps those of another. Hashing them takes a
few milliseconds a run.
"""

from __future__ import annotations

import hashlib
import importlib.metadata as metadata
import importlib.util
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .rollout_code import imported_conflictbench, policy_modules, rollout_files

__all__ = [
    "code_identity",
    "code_pins",
    "distribution_files",
    "file_hashes",
    "files_digest",
]

_PIN = re.compile(r"^(?P<name>[A-Za-z0-9._-]+)==(?P<version>\S+)$")
_SKIPPED_PARTS = {"__pycache__", ".pytest_cache"}
#: Files no import reads: an editor's swap and backup files, a patch's leftovers (they must not replay a store).
_NOT_CODE = (".pyc", ".swp", ".swo", ".orig", ".rej", ".bak", "~")


def file_hashes(files: Iterable[tuple[str, Path]]) -> dict[str, str]:
    """Each file's content digest (16 hex digits), by its name: the manifest a store keeps of a pin's code."""
    return {name: hashlib.sha256(path.read_bytes()).hexdigest()[:16] for name, path in sorted(files)}


def files_digest(hashes: dict[str, str]) -> str:
    """12 hex digits over a manifest (names and content digests, in name order)."""
    text = "".join(f"{name}\0{digest}\n" for name, digest in sorted(hashes.items()))
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _package_files(package: str, dist: metadata.Distribution | None = None) -> list[tuple[str, Path]]:
    """Every file of a package (or module), by its path from the package's parent folder: where ``dist``
    installed it, else (an editable install, whose files stay in its tree) where Python finds it."""
    roots: list[Path] = []
    if dist is not None and "." not in package:
        here = Path(str(dist.locate_file(package)))
        if here.is_dir():
            roots = [here]
        elif here.with_suffix(".py").is_file():
            return [(f"{package}.py", here.with_suffix(".py"))]
    if not roots:
        spec = importlib.util.find_spec(package)
        if spec is None:
            return []
        if spec.submodule_search_locations:
            roots = [Path(p) for p in spec.submodule_search_locations]
        elif spec.origin and spec.origin not in ("built-in", "frozen"):
            path = Path(spec.origin)
            return [(path.name, path)]
        else:
            return []
    found = []
    for root in roots:
        for path in root.rglob("*"):
            parts = path.relative_to(root).parts
            if (path.is_file() and not _SKIPPED_PARTS & set(parts) and not path.name.endswith(_NOT_CODE)
                    and not path.name.startswith(".")):  # fmt: skip
                found.append(("/".join([*package.split("."), *parts]), path))
    return found


def _top_level(dist: metadata.Distribution) -> list[str]:
    listed = (dist.read_text("top_level.txt") or "").split()
    if listed:
        return listed
    name = dist.metadata["Name"]
    return sorted(top for top, dists in metadata.packages_distributions().items() if name in dists)


def distribution_files(name: str, roots: Iterable[str] = ()) -> list[tuple[str, Path]]:
    """The files of distribution ``name`` that can change a rollout: all of its packages' files, but for
    conflictbench those a rollout runs from ``roots`` (the modules defining the policy, what plugins import of it)
    on (:func:`.rollout_code.rollout_files`)."""
    dist = metadata.distribution(name)
    if dist.metadata["Name"] == "conflictbench":
        return rollout_files(roots)
    return [f for top in _top_level(dist) for f in _package_files(top, dist)]


def _conflictbench_requirements(name: str) -> set[str]:
    """The installed conflictbench distributions ``name`` requires (a plugin's conflictbench-serving), deeply."""
    found: set[str] = set()
    todo = [name]
    while todo:
        for requirement in metadata.requires(todo.pop()) or ():
            if "extra ==" in requirement:
                continue
            wanted = re.match(r"[A-Za-z0-9._-]+", requirement)[0]
            if wanted.lower().replace("_", "-").startswith("conflictbench") and wanted not in found:
                try:
                    metadata.distribution(wanted)
                except metadata.PackageNotFoundError:
                    continue
                found.add(wanted)
                todo.append(wanted)
    return found


def code_identity(pins: Iterable[str], policy: Any = None) -> tuple[tuple[str, ...], dict[str, dict[str, str]]]:
    """``name==version`` pins (``Plugins.provenance``), each installed distribution's followed by the digest of its
    rollout files (``name==version files=0123456789ab``), with the conflictbench distributions they require; and
    each digested pin's manifest (its files' digests, to say later which files changed). Pins that name no
    installed distribution (a plugin object registered in-process) stay as they are. conflictbench's files are
    those a rollout of ``policy`` (its ``PolicySpec``) runs, with what the other distributions import of it."""
    names: dict[str, str] = {}
    kept: set[str] = set()
    for pin in pins:
        match = _PIN.match(pin)
        try:
            dist = metadata.distribution(match["name"]) if match else None
        except metadata.PackageNotFoundError:
            dist = None
        if dist is None:
            kept.add(pin)
            continue
        names[dist.metadata["Name"]] = dist.version
        for required in _conflictbench_requirements(dist.metadata["Name"]):
            names.setdefault(required, metadata.distribution(required).version)
    files = {name: distribution_files(name) for name in names if name != "conflictbench"}
    roots = imported_conflictbench(path for found in files.values() for _, path in found)
    if "conflictbench" in names:
        files["conflictbench"] = rollout_files(roots | (policy_modules(policy) if policy is not None else set()))
    manifests = {}
    for name, version in names.items():
        hashes = file_hashes(files[name])
        manifests[f"{name}=={version} files={files_digest(hashes)}"] = hashes
    return tuple(sorted(kept | set(manifests))), manifests


def code_pins(pins: Iterable[str], policy: Any = None) -> tuple[str, ...]:
    """The pins of :func:`code_identity`, without the manifests."""
    return code_identity(pins, policy)[0]
