"""Why a plan plays again what earlier runs of the same policy stored: what differs in the identity.

A store keeps, beside its episodes, the manifest of each code pin its runs used (``code/``: each file's digest), so
a changed digest can be told as the files that changed ("code changed: conflictbench_pi0 (processing.py)").
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from conflictbench.hosting.environments import version_changes
from conflictbench.store import EpisodeStore
from conflictbench.store.durable import stops_when_full
from conflictbench.store.paths import write_inside

from .stack import SIMULATOR_COLUMNS, extra_stack

#: The newest episodes of the policy that are compared (as the time estimate reads them).
SAMPLE = 20
#: Files named at most, per distribution.
NAMED_FILES = 3


def _manifest_path(root: Path, pin: str) -> Path:
    name_version, _, digest = pin.partition(" files=")
    return root / "code" / f"{name_version.replace('==', '-')}-{digest}.json"


def keep_manifests(root: Path, manifests: Mapping[str, Mapping[str, str]]) -> None:
    """Store each pin's manifest once (a few kB each; written beside the episodes of the run that used it)."""
    for pin, hashes in manifests.items():
        path = _manifest_path(root, pin)
        if not path.exists():
            with stops_when_full(root):  # a full disk: one line, no half-written manifest left; never through a link
                write_inside(root, path, json.dumps(dict(hashes), indent=0, sort_keys=True).encode(), "the store")


def _by_name(pins) -> dict[str, str]:
    return {pin.split(" ")[0].split("==")[0]: pin for pin in pins}


def _files_changed(before: Mapping[str, str], now: Mapping[str, str]) -> str:
    """The files edited or added, named; those no longer counted (deleted, or off the rollout's path), counted."""
    files = sorted(f for f in now if before.get(f) != now[f])
    more = f" and {len(files) - NAMED_FILES} more" if len(files) > NAMED_FILES else ""
    gone = len(before.keys() - now.keys())
    left = f"{gone} file{'s' if gone > 1 else ''} no longer counted" if gone else ""
    return "; ".join(part for part in (", ".join(files[:NAMED_FILES]) + more, left) if part)


def code_changes(root: Path, before: tuple[str, ...], now: tuple[str, ...]) -> list[str]:
    """In words, how the code pins ``now`` differ from ``before`` (files named where both manifests are kept)."""
    old, new = _by_name(before), _by_name(now)
    changes = []
    for name in sorted(old.keys() | new.keys()):
        was, is_ = old.get(name), new.get(name)
        if was == is_:
            continue
        if was is None or is_ is None:
            changes.append(f"{name} {'added' if was is None else 'removed'}")
            continue
        old_version, new_version = was.split(" ")[0].split("==")[1], is_.split(" ")[0].split("==")[1]
        if old_version != new_version:
            changes.append(f"{name} {old_version} -> {new_version}")
            continue
        if " files=" not in was:
            changes.append(f"{name}: its code is now identified by content (this store's episodes by version)")
            continue
        try:
            a = json.loads(_manifest_path(root, was).read_text())
            b = json.loads(_manifest_path(root, is_).read_text())
        except (OSError, ValueError):
            changes.append(f"code changed: {name}")
            continue
        changes.append(f"code changed: {name} ({_files_changed(a, b)})")
    return changes


def _stack_parts(pins: tuple[str, ...]) -> dict[str, str]:
    parts = {}
    for pin in pins:
        name, _, version = pin.partition("=") if pin.startswith("device=") else pin.partition("==")
        parts[name] = version
    return parts


def stack_changes(before: tuple[str, ...], now: tuple[str, ...]) -> str:
    """How two model stacks (``EpisodeRecord.model_stack``) differ, in words: ``device cpu -> cuda, lerobot 0.6.1 ->
    0.6.2, accelerate added`` (the first few), or which of them the server did not report."""
    if "unreported" in before + now:
        return f"{'unreported' if 'unreported' in before else 'reported'} -> " + (
            "unreported" if "unreported" in now else "reported"
        )
    words = version_changes(_stack_parts(before), _stack_parts(now))
    more = f" and {len(words) - NAMED_FILES} more" if len(words) > NAMED_FILES else ""
    return ", ".join(words[:NAMED_FILES]) + more


def identity_changes(
    store: EpisodeStore,
    policy: str,
    config_hash: str,
    code_versions: tuple[str, ...],
    settings: str,
    simulator: Mapping[str, str],
    model_stack: tuple[str, ...] = (),
) -> list[str] | None:
    """What differs between this run's identity and that of the newest stored episodes of ``policy`` with the
    same settings (another variant's are other episodes, nothing to explain): None where there are none, or some
    of them share this identity (nothing changed: the plan holds new episodes)."""
    folder = store.episodes_dir / policy
    files = sorted(folder.glob("*.parquet"), key=lambda p: p.stat().st_mtime)[-SAMPLE:]
    if not files:
        return None
    columns = ["episode_id", "config_hash", "code_versions", "model_stack", "policy_settings", "sim_stack",
               *SIMULATOR_COLUMNS]  # fmt: skip
    rows = {r["episode_id"]: r for r in store.read_table(columns, [f.stem for f in files]).to_pylist()}
    alike = [rows[f.stem] for f in files if f.stem in rows and (rows[f.stem]["policy_settings"] or "") == settings]
    if not alike or any(r["config_hash"] == config_hash for r in alike):
        return None
    newest = alike[-1]
    changes = code_changes(store.root, tuple(newest["code_versions"] or ()), tuple(code_versions))
    for column in SIMULATOR_COLUMNS:
        if newest[column] and simulator.get(column) and newest[column] != simulator[column]:
            changes.append(f"{column.removesuffix('_version')} {newest[column]} -> {simulator[column]}")
    was = dict(pin.split("=", 1) for pin in newest["sim_stack"] or ())
    now = dict(pin.split("=", 1) for pin in extra_stack(dict(simulator)))
    if was or newest["sim_stack"] is not None:  # stores written before the column say nothing of it
        changes += version_changes(was, now)
    if newest["model_stack"] and tuple(newest["model_stack"]) != tuple(model_stack):
        changes.append(f"model stack changed: {stack_changes(tuple(newest['model_stack']), tuple(model_stack))}")
    return changes or ["the model's identity or declared traits changed (its checkpoint, model stack, or budgets)"]
