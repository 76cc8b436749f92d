"""Merging episode stores written on different machines (``conflictbench merge OUT SHARD...``).

An episode's id names everything that decides its rollout (the policy, its settings and code, the simulator
stack, the episode itself), so one id in two shards is one episode played twice: the copy already merged stays
and the other is dropped (counted; counted apart where its rollout differs: a policy that is not deterministic
across machines). Where the two copies record other versions of the code or the simulator, they are not the
same experiment and the merge is refused before anything is written. Episodes the serving infrastructure ended
(``replay/``) are left out: the next run plays them again.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa

from conflictbench.core import StoreFull, UserError

from . import paths
from .check import left_out, read_intact
from .episodes import SUFFIX, EpisodeStore
from .schema import ARRAY_COLUMNS

#: What must agree for two copies of one episode id to be the same experiment.
VERSION_COLUMNS = (
    "conflictbench_version",
    "plugin",
    "plugin_version",
    "code_versions",
    "libero_version",
    "robosuite_version",
    "mujoco_version",
    "numpy_version",
)


@dataclass(frozen=True)
class Copy:
    """One stored file of an episode: where, what versions it records, a digest of its rollout."""

    path: Path
    policy: str
    episode_id: str
    versions: tuple
    rollout: str


@dataclass
class MergePlan:
    new: list[Copy] = field(default_factory=list)
    duplicates: int = 0
    differing: list[tuple[Copy, Copy]] = field(default_factory=list)
    """Duplicates whose rollout differs from the copy kept (same versions)."""
    clashes: list[tuple[Copy, Copy]] = field(default_factory=list)
    left_out_replays: int = 0


def _digest_column(digest, name: str, column: pa.ChunkedArray) -> None:
    """A nested list column into a rollout's digest: its name, the lengths at every level, then its numbers."""
    array = column.combine_chunks()
    digest.update(name.encode() + b"\0")
    while pa.types.is_list(array.type) or pa.types.is_fixed_size_list(array.type):
        # a null list has no length: -1 (never a float NaN cast to an integer, which numpy warns about)
        lengths = array.value_lengths().fill_null(-1).to_numpy(zero_copy_only=False).astype("int64")
        digest.update(len(lengths).to_bytes(8, "little") + lengths.tobytes())
        array = array.flatten()
    digest.update(array.fill_null(float("nan")).to_numpy(zero_copy_only=False).astype("float64").tobytes())


def read_copy(path: Path) -> Copy | None:
    """One episode file's identity, recorded versions and a digest of its rollout (its arrays). Read through the
    store's schema, as the store reads it (a file from before a column was added has it empty)."""
    try:
        # placed=False: a file naming another place is refused below in one line (nothing merged), not left out
        tables = read_intact([path], ["policy", "episode_id", *VERSION_COLUMNS, *ARRAY_COLUMNS], on_damage=left_out,
                             placed=False)  # fmt: skip
    except (pa.ArrowException, OSError) as exc:
        raise UserError(f"cannot read {path} as a stored episode: {exc}") from None
    if not tables:  # damaged (named, left in place: a shard is only read) or gone meanwhile: left out (#42)
        return None
    [table] = tables
    if table.num_rows != 1:
        raise UserError(f"{path} holds {table.num_rows} rows, not one episode")
    row = table.select(["policy", "episode_id", *VERSION_COLUMNS]).to_pylist()[0]
    names = _names(path, row["policy"], row["episode_id"])  # refused before its arrays are looked at
    digest = hashlib.sha256()
    for name in ARRAY_COLUMNS:
        _digest_column(digest, name, table[name])
    versions = tuple(tuple(row[k] or ()) if k == "code_versions" else row[k] for k in VERSION_COLUMNS)
    return Copy(path, *names, versions, digest.hexdigest()[:20])


def _names(path: Path, policy: object, episode_id: object) -> tuple[str, str]:
    """The policy and episode id a file holds, which become the path of its copy: each one plain name, and the
    ones its own path says (``<policy>/<episode id>.parquet``). A shard is data from another machine, never a
    path: a name with a separator or ``..`` would put the copy outside the store (#42), and a file renamed from
    another episode's would be counted under one id and stored under another."""
    where = f"{path}: "
    paths.check_name("policy", policy, where)
    paths.check_name("episode id", episode_id, where)
    if (path.parent.name, path.name) != (policy, f"{episode_id}{SUFFIX}"):
        raise UserError(f"{where}holds episode {episode_id} of {policy}, which its name does not say (renamed or "
                        f"crafted): nothing merged")  # fmt: skip
    return policy, episode_id  # type: ignore[return-value]


def _describe(a: Copy, b: Copy) -> str:
    diffs = [f"{n} {x!r} vs {y!r}" for n, x, y in zip(VERSION_COLUMNS, a.versions, b.versions, strict=True) if x != y]
    return f"{a.episode_id} ({a.path.parents[2]} and {b.path.parents[2]}): {'; '.join(diffs)}"


def plan_merge(
    out: EpisodeStore, shards: Sequence[EpisodeStore], on_file: Callable[[], None] | None = None
) -> MergePlan:
    """What merging ``shards`` into ``out`` would do; reads every file, writes nothing."""
    plan = MergePlan()
    kept: dict[str, Copy] = {}
    waiting: set[str] = set()
    for store in (out, *shards):
        for path in store.kept_files():
            copy = read_copy(path)
            if on_file is not None:
                on_file()
            if copy is None:
                continue
            first = kept.get(copy.episode_id)
            if first is None:
                kept[copy.episode_id] = copy
                if store is not out:
                    plan.new.append(copy)
            elif first.versions != copy.versions:
                plan.clashes.append((first, copy))
            else:
                plan.duplicates += 1
                if first.rollout != copy.rollout:
                    plan.differing.append((first, copy))
        if store is not out:
            waiting.update(p.stem for p in store.waiting_files())
    plan.left_out_replays = len(waiting - set(kept))  # played again somewhere: not left out
    return plan


def merge_stores(out: EpisodeStore, shards: Sequence[EpisodeStore], *, dry_run: bool = False,
                 on_file: Callable[[], None] | None = None) -> MergePlan:  # fmt: skip
    """Copy every episode of ``shards`` that ``out`` lacks into it, each file whole or not at all (copied under a
    temporary name, then renamed); refused, writing nothing, where two copies of an episode record other versions."""
    roots = [out.root.resolve(), *(s.root.resolve() for s in shards)]
    for shard in shards:
        if not paths.is_store(shard.root):
            raise UserError(f"{shard.root} is not an episode store (no {shard.episodes_dir.name}/ folder)")
    if len(set(roots)) != len(roots):
        raise UserError("the output and the shards must be different stores (one was named twice)")
    plan = plan_merge(out, shards, on_file)
    if plan.clashes:
        shown = "\n  ".join(_describe(a, b) for a, b in plan.clashes[:5])
        more = f"\n  ... and {len(plan.clashes) - 5} more" if len(plan.clashes) > 5 else ""
        raise UserError(
            f"nothing merged: {len(plan.clashes)} episode(s) were played with other versions in different stores "
            f"(not the same experiment):\n  {shown}{more}"
        )
    if not dry_run:
        for done, copy in enumerate(plan.new):
            try:
                out.copy_in(copy.path, copy.policy, copy.episode_id)
            except StoreFull as exc:
                raise MergeFull(exc.root, exc.reason, done, len(plan.new)) from None
    return plan


class MergeFull(StoreFull):
    """A merge whose output's file system took no more: said in a merge's words (not a run's ``run.out``)."""

    def __init__(self, root: str, reason: str, stored: int | None = None, total: int = 0):
        super().__init__(root, reason, stored)
        self.args, self.total = (root, reason, stored, total), total

    def __str__(self) -> str:
        return (
            f"no room left in the store {self.root} while merging ({self.reason}): merged {self.stored} of "
            f"{self.total} episode(s), each whole, no partial copy left; free space on its disk (`conflictbench "
            f"prune {self.root} --delete` removes superseded episodes) or merge into another OUT, then run the same "
            "merge again: it copies the rest"
        )
