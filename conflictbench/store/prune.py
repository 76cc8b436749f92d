"""Superseded episodes: those played again under a newer identity, which no run or report of today's code reads.

Episodes are compared by what a user chose, not by how it was played: the policy, its settings and declared
identity (a checkpoint's fingerprint: two checkpoints are two models, never each other's successor), the episode
itself (LIBERO suite, task, initial state, prompt condition, the case, its suite, the prompt text, seed) and its step
budget (``run.max_steps``: a capped smoke test does not supersede a full run). Of the
episodes that agree on all of it, those of the identity played last (the newest ``created_at``) are current; the
others, played under other code, another simulator or model stack, or another step budget, are superseded. An
episode waiting to be played again (``replay/``) is superseded the same way.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

from conflictbench.core import UserError

from .episodes import SUFFIX, EpisodeStore
from .paths import unlink_inside

#: What a user chose for an episode; episodes agreeing on these are one episode played under several identities.
CHOSEN = ("policy", "policy_settings", "max_steps", "policy_identity", "suite", "task_id", "init_state", "prompt",
          "case_id", "conflict_suite", "prompt_text", "seed")  # fmt: skip
#: Columns stores written before them hold as null: such an episode joins the one group that otherwise matches.
LATER_COLUMNS = ("policy_identity", "conflict_suite")


@dataclass(frozen=True)
class Superseded:
    policy: str
    episode_id: str
    path: Path
    bytes: int


def superseded(store: EpisodeStore) -> list[Superseded]:
    """The store's superseded episodes, by policy and id."""
    files = {p.name[: -len(SUFFIX)]: p for p in store.files()}
    if not files:
        return []
    rows = store.read_table(columns=["episode_id", "config_hash", "created_at", *CHOSEN]).to_pylist()
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for row in rows:
        groups[tuple("" if row[c] is None else row[c] for c in CHOSEN)].append(row)
    _join_older_rows(groups)
    # A file is condemned only by its own row: the one row naming its id, of the policy its folder names. A file
    # whose contents name another episode (renamed, crafted) must not get that episode's file deleted (#42).
    named = Counter(row["episode_id"] for row in rows)
    out = []
    for group in groups.values():
        current = max(group, key=lambda r: r["created_at"] or "")["config_hash"]
        for row in group:
            path = files.get(row["episode_id"])
            if row["config_hash"] == current or path is None or named[row["episode_id"]] != 1:
                continue
            if path.parent.name == row["policy"]:
                out.append(Superseded(row["policy"], row["episode_id"], path, path.stat().st_size))
    return sorted(out, key=lambda s: (s.policy, s.episode_id))


def remove(store: EpisodeStore, items: list[Superseded]) -> int:
    """Delete the superseded episodes' files; how many were there. Never through a link (#42): the listing skipped
    linked files and folders, and a folder turned into a link since is refused in one line, not followed. A file
    the system will not remove (a store this user may only read) stops it in one line saying how many went."""
    removed = 0
    for item in items:
        try:
            removed += unlink_inside(store.root, item.path)
        except OSError as exc:
            raise UserError(f"removed {removed} of {len(items)} superseded episodes; cannot remove {item.path}: "
                            f"{exc.strerror or exc}") from None  # fmt: skip
    return removed


def _join_older_rows(groups: dict[tuple, list[dict]]) -> None:
    """Rows of a store written before ``LATER_COLUMNS`` existed (null there) join the one group that matches them on
    every other column, where there is exactly one: the same episode, played again since under today's code."""
    later = [CHOSEN.index(c) for c in LATER_COLUMNS]

    def rest(key: tuple) -> tuple:
        return tuple(v for i, v in enumerate(key) if i not in later)

    for key in [k for k in groups if all(k[i] == "" for i in later)]:
        matches = [k for k in groups if k != key and rest(k) == rest(key)]
        if len(matches) == 1:
            groups[matches[0]].extend(groups.pop(key))
