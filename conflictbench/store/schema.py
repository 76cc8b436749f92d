"""The episode store's public schema: one Parquet row per episode (documented in the README).

Arrays are nested lists of float64 (``eef_pos``: list of 3-vectors, ``target_pos``: list of lists
of 3-vectors, ``actions``/``raw_actions``: list of 7-vectors) so pandas, pyarrow and DuckDB read
them without any conflictbench code.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import numpy as np
import pyarrow as pa

from conflictbench.core import ACTION_DIM, EpisodeRecord

SCHEMA_VERSION = 1

_VEC3 = pa.list_(pa.float64(), 3)
_ACTION = pa.list_(pa.float64(), ACTION_DIM)

SCHEMA = pa.schema(
    [
        # keys
        ("policy", pa.string()),
        ("suite", pa.string()),
        ("task_id", pa.int32()),
        ("init_state", pa.int32()),
        ("prompt", pa.string()),
        ("case_id", pa.string()),
        ("family", pa.string()),
        ("level", pa.string()),
        ("instruction", pa.string()),
        ("seed", pa.int64()),
        # outcome
        ("success", pa.bool_()),
        ("steps", pa.int32()),
        ("error", pa.string()),
        ("error_kind", pa.string()),
        ("sim_warnings", pa.list_(pa.string())),
        # process
        ("eef_pos", pa.list_(_VEC3)),
        ("target_pos", pa.list_(pa.list_(_VEC3))),
        ("target_names", pa.list_(pa.string())),
        ("actions", pa.list_(_ACTION)),
        ("raw_actions", pa.list_(_ACTION)),
        # context
        ("episode_id", pa.string()),
        ("conflict_suite", pa.string()),
        ("base_instruction", pa.string()),
        ("prompt_text", pa.string()),
        ("max_steps", pa.int32()),
        ("warmup_steps", pa.int32()),
        ("control_mode", pa.string()),
        # provenance
        ("conflictbench_version", pa.string()),
        ("plugin", pa.string()),
        ("plugin_version", pa.string()),
        ("code_versions", pa.list_(pa.string())),
        ("model_stack", pa.list_(pa.string())),
        ("libero_version", pa.string()),
        ("robosuite_version", pa.string()),
        ("mujoco_version", pa.string()),
        ("numpy_version", pa.string()),
        ("sim_stack", pa.list_(pa.string())),
        ("policy_identity", pa.string()),
        ("config_hash", pa.string()),
        ("policy_settings", pa.string()),
        ("wall_time_s", pa.float64()),
        ("sim_time_s", pa.float64()),
        ("created_at", pa.string()),
    ],
    metadata={"conflictbench.schema_version": str(SCHEMA_VERSION)},
)

ARRAY_COLUMNS = ("eef_pos", "target_pos", "actions", "raw_actions")
_FIELD_NAMES = [f.name for f in dataclasses.fields(EpisodeRecord)]
assert set(_FIELD_NAMES) == set(SCHEMA.names), "EpisodeRecord and the store schema must list the same columns"


def _offsets(lengths: list[int]) -> pa.Array:
    return pa.array(np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)]).astype(np.int32))


def _nested(arrays: list[np.ndarray], width: int, ndim: int) -> pa.Array:
    """list<fixed_size_list<float64, width>> (ndim 2) or list<list<...>> (ndim 3) from ndarrays."""
    arrays = [np.asarray(a, dtype=np.float64) for a in arrays]
    for a in arrays:  # never reshape silently: a wrong width is a bug upstream
        if a.ndim != ndim or a.shape[-1] != width:
            raise ValueError(f"expected an array of {ndim} dimensions ending in {width}, got shape {a.shape}")
    flat = np.concatenate([a.reshape(-1) for a in arrays]) if arrays else np.zeros(0)
    values: pa.Array = pa.FixedSizeListArray.from_arrays(pa.array(flat, type=pa.float64()), width)
    if ndim == 3:  # each step holds K vectors
        per_step = [a.shape[1] for a in arrays for _ in range(a.shape[0])]
        values = pa.ListArray.from_arrays(_offsets(per_step), values)
    return pa.ListArray.from_arrays(_offsets([a.shape[0] for a in arrays]), values)


def records_to_table(records: Iterable[EpisodeRecord]) -> pa.Table:
    records = list(records)
    columns: dict[str, Any] = {}
    for name in SCHEMA.names:
        values = [getattr(r, name) for r in records]
        if name in ARRAY_COLUMNS:
            width = ACTION_DIM if "actions" in name else 3
            try:
                columns[name] = _nested(values, width, ndim=3 if name == "target_pos" else 2)
            except ValueError as exc:
                raise ValueError(f"column {name}: {exc}") from None
        elif name in ("target_names", "code_versions", "model_stack", "sim_stack", "sim_warnings"):
            columns[name] = pa.array([list(v) for v in values], type=SCHEMA.field(name).type)
        else:
            columns[name] = pa.array(values, type=SCHEMA.field(name).type)
    return pa.table(columns, schema=SCHEMA)


def _column_arrays(column: pa.ChunkedArray, inner: tuple[int, ...]) -> list[np.ndarray]:
    """Inverse of :func:`_nested`: one ndarray per row, shaped (H, *inner)."""
    out: list[np.ndarray] = []
    for chunk in column.chunks:
        outer_offsets = chunk.offsets.to_numpy()
        level = chunk.values
        if len(inner) == 2:
            mid_offsets = level.offsets.to_numpy()
            flat = level.values.values.to_numpy(zero_copy_only=False)
            for i in range(len(chunk)):
                a, b = outer_offsets[i], outer_offsets[i + 1]
                h = b - a
                k = (mid_offsets[b] - mid_offsets[a]) // h if h else 0
                lo, hi = mid_offsets[a] * 3, mid_offsets[b] * 3
                out.append(flat[lo:hi].reshape(h, k, 3))
        else:
            flat = level.values.to_numpy(zero_copy_only=False)
            d = inner[0]
            for i in range(len(chunk)):
                a, b = outer_offsets[i], outer_offsets[i + 1]
                out.append(flat[a * d : b * d].reshape(b - a, d))
    return out


LIST_COLUMNS = ("target_names", "code_versions", "sim_warnings", "model_stack", "sim_stack")
TEXT_COLUMNS = ("policy_settings", "policy_identity")


def normalize_scalars(row: dict[str, Any]) -> dict[str, Any]:
    """A row's scalar columns as :class:`EpisodeRecord` holds them: lists as tuples, and the columns stores written
    before them hold as null as empty."""
    for name in LIST_COLUMNS:
        row[name] = tuple(row[name] or ())
    for name in TEXT_COLUMNS:
        row[name] = row[name] or ""
    return row


def table_to_records(table: pa.Table) -> list[EpisodeRecord]:
    table = table.select(SCHEMA.names)
    arrays = {
        "eef_pos": _column_arrays(table["eef_pos"], (3,)),
        "target_pos": _column_arrays(table["target_pos"], (0, 3)),
        "actions": _column_arrays(table["actions"], (ACTION_DIM,)),
        "raw_actions": _column_arrays(table["raw_actions"], (ACTION_DIM,)),
    }
    scalars = table.drop_columns(list(ARRAY_COLUMNS)).to_pylist()
    records = []
    for i, row in enumerate(scalars):
        normalize_scalars(row)
        for name in ARRAY_COLUMNS:
            row[name] = arrays[name][i]
        records.append(EpisodeRecord(**row))
    return records
