"""The pairs a viewer shows: chosen from a store, with their measures, the case behind each, and plot data."""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from conflictbench.core import EpisodeRecord, Pair, UserError
from conflictbench.metrics.aggregate import sort_groups, with_model
from conflictbench.report.from_store import light_records
from conflictbench.report.summary import pair_up
from conflictbench.store import EpisodeStore

OUTCOMES = {  # (reference succeeded, conflict completed the original goal) -> words
    (True, True): "completed anyway",
    (True, False): "qualified failure",
    (False, True): "only the conflict completed",
    (False, False): "both failed",
}
FILTERS = ("model", "family", "level", "prompt", "outcome")


@dataclass
class Selection:
    """Which pairs to show: each field a set of accepted values (empty: any)."""

    model: set[str] = field(default_factory=set)
    family: set[str] = field(default_factory=set)
    level: set[str] = field(default_factory=set)
    prompt: set[str] = field(default_factory=set)
    outcome: set[str] = field(default_factory=set)

    def check(self, rows: pd.DataFrame) -> None:
        """A value that names nothing in the store is the user's mistake: say what there is."""
        for name in FILTERS:
            unknown = getattr(self, name) - set(rows[name].astype(str))
            if unknown:
                have = ", ".join(sorted(set(rows[name].astype(str)))) or "none"
                raise UserError(f"no pairs with {name} {', '.join(sorted(unknown))} in this store (there are: {have})")

    def mask(self, rows: pd.DataFrame) -> pd.Series:
        keep = pd.Series(True, index=rows.index)
        for name in FILTERS:
            if getattr(self, name):
                keep &= rows[name].astype(str).isin(getattr(self, name))
        return keep


def pair_rows(store: EpisodeStore) -> tuple[list[Pair], pd.DataFrame]:
    """Every scorable pair of the store (keys only, no arrays) and one row of keys per pair, in store order."""
    pairs, _ = pair_up(light_records(store))
    rows = pd.DataFrame(
        {
            "policy": [p.conflict.policy for p in pairs],
            "config_hash": [p.conflict.config_hash for p in pairs],
            "policy_settings": [p.conflict.policy_settings for p in pairs],
            "family": [p.conflict.family for p in pairs],
            "level": [p.conflict.level for p in pairs],
            "prompt": [p.conflict.prompt for p in pairs],
            "case_id": [p.conflict.case_id for p in pairs],
            "outcome": [OUTCOMES[(bool(p.reference.success), bool(p.conflict.success))] for p in pairs],
            "conflict_episode": [p.conflict.episode_id for p in pairs],
        }
    )
    return pairs, with_model(rows)


def choose(store: EpisodeStore, selection: Selection, *, allow_none: bool = False) -> tuple[list[Pair], pd.DataFrame]:
    """The pairs the filters choose, in the paper's order; with ``allow_none``, none where the store has none (it
    may hold reference episodes alone, as ``conflictbench reproduce`` plays them)."""
    pairs, rows = pair_rows(store)
    if not pairs and allow_none:
        return [], rows
    if not pairs:
        raise UserError(f"{store.root} holds no pairs to show (a conflict episode and its reference)")
    selection.check(rows)
    keep = selection.mask(rows)
    if not keep.any():
        raise UserError("no pair matches all of the filters given")
    rows = rows.assign(position=range(len(rows)))[keep.to_numpy()]
    rows = sort_groups(rows, ["model", "family", "level", "prompt", "case_id"])  # the paper's order
    return [pairs[i] for i in rows.pop("position")], rows


def target_distance(record: EpisodeRecord) -> np.ndarray:
    """d_t of TAR: the end effector's distance to the nearest target at each recorded state."""
    if record.target_pos.size == 0:
        return np.full(len(record.eef_pos), np.nan)
    return np.min(np.linalg.norm(record.target_pos - record.eef_pos[:, None, :], axis=2), axis=1)


def _rounded(array: np.ndarray, digits: int) -> list:
    return np.round(np.nan_to_num(np.asarray(array, dtype=float), nan=-1.0), digits).tolist()


def episode_data(record: EpisodeRecord) -> dict[str, Any]:
    """What the page plots of one episode (0.1 mm and 1e-3 action units: far below what a plot shows)."""
    return {
        "eef": _rounded(record.eef_pos, 4),
        "distance": _rounded(target_distance(record), 4),
        "actions": _rounded(record.actions, 3),
        "targets": _rounded(record.target_pos[0], 4) if len(record.target_pos) else [],
    }


def _override_value(value: Any) -> str:
    """``value`` in Hydra's override grammar (quoted where a plain word would be read otherwise)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(_override_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ",".join(f"{k}:{_override_value(v)}" for k, v in value.items()) + "}"
    text = str(value)
    if re.fullmatch(r"[A-Za-z_][\w./-]*", text) and text not in ("null", "true", "false"):
        return text
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


def play_again_command(conflict: EpisodeRecord) -> str:
    """The command that plays this pair (its conflict episode and the reference it needs) again."""
    import shlex

    settings = json.loads(conflict.policy_settings or "{}") or {}  # "null": a policy without settings (noop)
    overrides = [f"model={conflict.policy}"]
    overrides += [f"model.{key}={_override_value(value)}" for key, value in sorted(settings.items())]
    overrides += [
        f"run.cases=[{conflict.case_id}]",
        f"run.init_states=[{conflict.init_state}]",
        f"prompt={conflict.prompt}",
        f"run.seed={conflict.seed}",
    ]
    return " ".join(["conflictbench", *(shlex.quote(o) for o in overrides)])
