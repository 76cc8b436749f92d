"""Outcome rates, means over D_QF and paired P0 - P1 differences, counted by hand."""

from __future__ import annotations

import math

import pytest
from scipy import stats
from testing_support import along_x, episode_record

from conflictbench.core import EpisodeRecord
from conflictbench.metrics import (
    aggregate,
    evaluate_pairs,
    failure_rate,
    make_pairs,
    pcsr,
    prompt_couples,
    prompt_differences,
    rgsr,
)


def episode(
    case=None,
    success=False,
    init=0,
    prompt="p0",
    policy="pi0",
    family=None,
    level=None,
    x=0.0,
    task=0,
    config="h1",
    settings="",
) -> EpisodeRecord:
    key = dict(policy=policy, task_id=task, init_state=init, prompt=prompt, instruction="i", case_id=case)
    identity = dict(config_hash=config, policy_settings=settings, episode_id=f"{policy}-{prompt}-{case}-{init}-{task}")
    path = along_x(0.0, x, action=(x, 0, 0, 0, 0, 0, 0))
    return episode_record(**key, **identity, **path, family=family, level=level, success=success)


def frame_of(records, metrics=("tar", "early20_ts", "ts", "ams")):
    pairs, orphans = make_pairs(records)
    assert not orphans
    return evaluate_pairs([p.reference for p in pairs], [p.conflict for p in pairs])


def test_a_reference_reused_by_k_pairs_counts_k_times():
    # reference A (succeeded) serves three conflicts, reference B (failed) one:
    # PCSR = 3/4 (per pair), not 1/2 (per reference)
    records = [
        episode(success=True, init=0),
        episode(success=False, init=1),
        episode("c1", init=0, family="grounding", level="L1"),
        episode("c2", init=0, family="grounding", level="L1", success=True),
        episode("c3", init=0, family="spatial", level="L1"),
        episode("c1", init=1, family="grounding", level="L1"),
    ]
    pairs, _ = make_pairs(records)
    assert (pcsr(pairs).k, pcsr(pairs).n) == (3, 4)
    assert (rgsr(pairs).k, rgsr(pairs).n) == (1, 4)
    row = aggregate(frame_of(records), ("model", "prompt"), ["ts"]).iloc[0]
    assert (row["pairs"], row["PCSR_k"], row["RGSR_k"]) == (4, 3, 1)
    assert row["PCSR"] == 0.75 and row["RGSR"] == 0.25 and row["dSR"] == 0.5
    # D_Q = the 3 pairs of reference A; D_QF = c1 and c3 of init 0: FR = 2/3
    assert (row["FR_k"], row["FR_n"]) == (2, 3) and row["FR"] == pytest.approx(2 / 3)
    assert (failure_rate(pairs).k, failure_rate(pairs).n) == (2, 3)


def test_fr_is_undefined_when_no_reference_succeeded():
    records = [
        episode(success=False),
        episode("c1", family="physical", level="L2"),
        episode("c2", family="physical", level="L2", success=True),
    ]
    row = aggregate(frame_of(records), ("model", "prompt"), ["ams"]).iloc[0]
    assert row["FR_n"] == 0 and row["FR_k"] == 0 and math.isnan(row["FR"])
    assert row["ams_qf_n"] == 0 and math.isnan(row["ams_qf"])
    assert failure_rate(make_pairs(records)[0]).value is None


def test_process_means_over_all_pairs_and_over_qualified_failures():
    # AMS with the reference moving 0.2 on dim 0 (I+ = 1): a conflict moving x has AMS = 1 - x / 0.2
    ref = episode(success=True, x=0.2)
    cons = [
        episode("a", x=0.05, family="spatial", level="L1"),  # AMS 0.75, QF
        episode("b", x=0.1, family="spatial", level="L1", success=True),  # AMS 0.5, not QF
        episode("c", x=0.15, family="physical", level="L3"),
    ]  # AMS 0.25, QF
    frame = frame_of([ref, *cons])
    assert list(frame["ams"]) == pytest.approx([0.75, 0.5, 0.25])
    row = aggregate(frame, ("model",), ["ams"]).iloc[0]
    assert row["ams"] == pytest.approx(0.5) and row["ams_n"] == 3
    assert row["ams_qf"] == pytest.approx(0.5) and row["ams_qf_n"] == 2  # (0.75 + 0.25) / 2
    by_family = aggregate(frame, ("model", "family"), ["ams"]).set_index("family")
    assert list(by_family.index) == ["spatial", "physical"]  # the paper's family order
    assert by_family.loc["spatial", "ams_qf"] == pytest.approx(0.75) and by_family.loc["spatial", "pairs"] == 2
    assert by_family.loc["physical", "ams"] == pytest.approx(0.25)


def test_groupings_keep_models_prompts_suites_and_cases_apart():
    records = [
        episode(success=True),
        episode(success=True, prompt="p1"),
        episode(policy="oft", success=False),
        episode("c1", family="grounding", level="L1"),
        episode("c1", prompt="p1", family="grounding", level="L1", success=True),
        episode("c1", policy="oft", family="grounding", level="L1"),
        episode("c2", policy="oft", family="instruction", level="L4"),
    ]
    frame = frame_of(records)
    by_model = aggregate(frame, ("model", "prompt"), [])
    assert [tuple(r) for r in by_model[["model", "prompt", "pairs", "PCSR_k", "RGSR_k"]].itertuples(index=False)] == [
        ("oft", "p0", 2, 0, 0),
        ("pi0", "p0", 1, 1, 0),
        ("pi0", "p1", 1, 1, 1),
    ]
    by_case = aggregate(frame, ("model", "case_id"), [])
    assert len(by_case) == 3 and set(by_case["case_id"]) == {"c1", "c2"}


def test_one_policy_with_two_settings_is_two_models():
    records = [
        episode(success=True, config="aaaaaaaa"),
        episode("c1", config="aaaaaaaa"),
        episode(success=False, config="bbbbbbbb"),
        episode("c1", config="bbbbbbbb"),
    ]
    table = aggregate(frame_of(records), ("model",), [])
    assert list(table["model"]) == ["pi0[aaaaaa]", "pi0[bbbbbb]"]
    assert list(table["PCSR_k"]) == [1, 0]


@pytest.mark.parametrize(
    "settings, labels",
    [
        (('{"scale": 1.0, "seed": 1}', '{"scale": 1.0, "seed": 2}'), ["pi0 seed=1", "pi0 seed=2"]),
        (('{"a": "x", "seed": 1}', '{"a": "y", "seed": 2}'), ["pi0 a=x seed=1", "pi0 a=y seed=2"]),
        (('{"seed": 1}', '{"seed": 1}'), ["pi0[aaaaaa]", "pi0[bbbbbb]"]),  # the same settings: other code
        (("", ""), ["pi0[aaaaaa]", "pi0[bbbbbb]"]),  # a store written before settings were kept
        (('{"seed": 1}', '{"seed": 1, "extra": true}'), ["pi0 extra=null", "pi0 extra=true"]),
    ],
)
def test_variants_of_one_policy_are_labelled_by_the_settings_that_differ(settings, labels):
    records = []
    for config, text in zip(("aaaaaaaa", "bbbbbbbb"), settings, strict=True):
        records += [episode(success=True, config=config, settings=text), episode("c1", config=config, settings=text)]
    table = aggregate(frame_of(records), ("model",), [])
    assert list(table["model"]) == labels


def test_paired_prompt_differences_match_p0_and_p1_of_the_same_case_and_state():
    records = []
    # two cases x two init states; under P0 the conflict completes the original goal in 3 of 4,
    # under P1 in 1 of 4; a P0-only case has no partner and is left out
    outcomes_p0 = {("c1", 0): True, ("c1", 1): True, ("c2", 0): True, ("c2", 1): False}
    outcomes_p1 = {("c1", 0): False, ("c1", 1): True, ("c2", 0): False, ("c2", 1): False}
    for init in (0, 1):
        records += [episode(success=True, init=init, x=0.2), episode(success=True, init=init, prompt="p1", x=0.2)]
    for (case, init), ok in outcomes_p0.items():
        records.append(episode(case, init=init, success=ok, x=0.1, family="spatial", level="L1"))  # AMS 0.5
    for (case, init), ok in outcomes_p1.items():
        records.append(episode(case, init=init, prompt="p1", success=ok, x=0.05, family="spatial", level="L1"))  # 0.75
    records.append(episode("c3", init=0, family="spatial", level="L1"))
    frame = frame_of(records)
    couples = prompt_couples(frame, ["ams"])
    assert len(couples) == 4
    summary = prompt_differences(couples, ["ams"], ranges={"ams": (0.0, 1.0)}).iloc[0]
    assert summary["pairs"] == 4 and summary["clusters"] == 1
    # RGSR: (3 - 1) / 4 = +0.5 on the matched couples; AMS: 0.5 - 0.75 = -0.25 for each couple
    assert summary["RGSR"] == pytest.approx(0.5) and summary["RGSR_n"] == 4
    assert (summary["RGSR_a"], summary["RGSR_b"]) == (0.75, 0.25)
    assert summary["ams"] == pytest.approx(-0.25)
    assert summary["PCSR"] == 0.0
    # one base task: nothing measures how tasks differ, so every interval is the whole range and nothing is called
    assert (summary["RGSR_lo"], summary["RGSR_hi"], summary["RGSR_p"]) == (-1.0, 1.0, 1.0)


def test_paired_prompt_differences_rest_on_base_tasks():
    records = []
    # 10 base tasks, one case each: under P0 the conflict completes the original goal in every task, under P1
    # in none; the references succeed under both
    for task in range(10):
        for prompt, ok in (("p0", True), ("p1", False)):
            records += [
                episode(success=True, prompt=prompt, task=task),
                episode("c1", prompt=prompt, task=task, success=ok, family="spatial"),
            ]
    summary = prompt_differences(prompt_couples(frame_of(records), []), []).iloc[0]
    assert (summary["pairs"], summary["clusters"], summary["RGSR"]) == (10, 10, 1.0)
    # every couple differs by +1: Wilson's bound for none of 10 base tasks differing, on the range [-1, 1]
    q = stats.t.ppf(0.975, 9)
    assert summary["RGSR_lo"] == pytest.approx(1 - 2 * q**2 / (10 + q**2)) and summary["RGSR_hi"] == 1.0
    assert summary["RGSR_p"] < 0.05
    assert summary["PCSR"] == 0.0 and summary["PCSR_lo"] < 0 < summary["PCSR_hi"] and summary["PCSR_p"] == 1.0


def test_aggregates_of_nothing_are_empty_not_errors():
    empty = evaluate_pairs([], [])
    assert aggregate(empty, ("model", "prompt"), ["ts"]).empty
    assert prompt_couples(empty, ["ts"]).empty
    assert prompt_differences(prompt_couples(empty, ["ts"]), ["ts"]).empty
