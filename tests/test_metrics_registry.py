"""Metrics come only from the registry: built-ins and plugins alike, batched or pair by pair."""

from __future__ import annotations

import gc
import math
import weakref

import pytest
from testing_support import along_x, episode_record

import conflictbench
from conflictbench.core import EpisodeRecord, Pair, Plugins, UserError, hookimpl
from conflictbench.metrics import evaluate_pairs, metric_specs, pair_metrics
from conflictbench.metrics.process import PerChunk, builtin_batch


def record(x_end: float, steps: int, case: str | None = "c1") -> EpisodeRecord:
    return episode_record(case_id=case, steps=steps, **along_x(0.5, x_end, action=(0.2, 0, 0, 0, 0, 0, 1.0)))


class PathRatio:
    """A batched-only plugin metric (conflict steps / reference steps) that counts its calls."""

    def __init__(self):
        self.chunks: list[int] = []

    def compute_many(self, references, conflicts):
        self.chunks.append(len(references))
        return [c.steps / r.steps if r.steps else None for r, c in zip(references, conflicts)]

    @hookimpl
    def conflictbench_register_metrics(self, register):
        register(
            "path_ratio",
            compute_many=self.compute_many,
            label="Path ratio",
            unit="%",
            higher_is_better=False,
            description="conflict steps / reference steps",
        )


def test_builtins_carry_their_labels_units_and_directions():
    specs = conflictbench.plugins(entry_points=False).metrics()
    shown = {n: (specs[n].label, specs[n].unit, specs[n].direction) for n in ("tar", "early20_ts", "ts", "ams")}
    assert shown == {
        "tar": ("TAR", "%", "lower"),
        "early20_ts": ("Early20 TS", "%", "lower"),
        "ts": ("TS", "%", "lower"),
        "ams": ("AMS", "%", "higher"),
    }
    assert all(specs[n].compute_many is not None for n in shown)


def test_a_registry_without_the_builtins_evaluates_only_its_own_metrics():
    plugin = PathRatio()
    plugins = Plugins(entry_points=False, extra=[plugin])
    refs = [record(0.1, 40, case=None), record(0.1, 0, case=None)]
    cons = [record(0.3, 10), record(0.3, 5)]
    frame = evaluate_pairs(refs, cons, plugins=plugins)
    assert [s.name for s in metric_specs(plugins)] == ["path_ratio"]
    assert not {"tar", "ts", "early20_ts", "ams"} & set(frame.columns)
    assert frame.at[0, "path_ratio"] == 0.25 and math.isnan(frame.at[1, "path_ratio"])  # None: undefined
    with pytest.raises(UserError) as err:
        metric_specs(plugins, ["ts"])
    assert str(err.value) == "unknown metric 'ts'; valid choices: path_ratio"


def test_a_compute_many_metric_is_called_once_per_chunk_and_for_one_pair():
    plugin = PathRatio()
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[plugin])
    refs = [record(0.1, 40, case=None)] * 5
    cons = [record(0.3, s) for s in (4, 8, 12, 16, 20)]
    frame = evaluate_pairs(refs, cons, plugins=plugins, chunk_size=2)
    assert plugin.chunks == [2, 2, 1]
    assert list(frame["path_ratio"]) == [0.1, 0.2, 0.3, 0.4, 0.5]
    spec = plugins.metrics()["path_ratio"]
    assert spec.compute is None and spec.compute_pair(Pair(refs[0], cons[0])) == 0.1
    assert pair_metrics(refs[0], cons[1], plugins=plugins)["path_ratio"] == 0.2


def test_the_builtins_share_one_kernel_pass_per_chunk():
    refs = [record(0.1, 1, case=None)] * 5
    cons = [record(0.3 + 0.01 * i, 1) for i in range(5)]
    before = builtin_batch.runs
    frame = evaluate_pairs(refs, cons, plugins=conflictbench.plugins(entry_points=False), chunk_size=2)
    assert builtin_batch.runs - before == 3  # three chunks, four metrics each
    assert frame["tar"].notna().all() and frame["ams"].notna().all()


def test_per_chunk_reuses_a_result_only_for_the_same_records_and_does_not_keep_them():
    calls = []
    shared = PerChunk(lambda refs, cons: calls.append(len(refs)) or object())
    refs, cons = [record(0.1, 1)], [record(0.2, 1)]
    first = shared(refs, cons)
    assert shared(list(refs), list(cons)) is first and calls == [1]  # the same records, other lists
    assert shared(refs, [record(0.2, 1)]) is not first and calls == [1, 1]  # an equal but other record
    probe = weakref.ref(refs[0])
    del refs, cons
    gc.collect()
    assert probe() is None  # a finished chunk is freed: memory stays bounded when streaming


def test_a_compute_many_with_the_wrong_length_is_undefined_with_a_warning():
    class Short:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("short", compute_many=lambda refs, cons: [1.0])

    plugins = Plugins(entry_points=False, extra=[Short()])
    with pytest.warns(UserWarning, match="short.*1 values for 2 pairs"):
        frame = evaluate_pairs([record(0.1, 1)] * 2, [record(0.2, 1)] * 2, plugins=plugins)
    assert frame["short"].isna().all()
