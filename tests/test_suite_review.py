"""Review decisions: stored beside the suite, honoured by the build, refused when stale or broken."""

from __future__ import annotations

import json

import pytest
from testing_support import TRAMPOLINE

from conflictbench.tasks.libero.base_tasks import base_task
from conflictbench.tasks.scene.facts import load_scene_facts
from conflictbench.tasks.scene.task_model import build_model
from conflictbench.tasks.suite.build import generate_task_cases, operator_entries
from conflictbench.tasks.suite.file import load_suite
from conflictbench.tasks.suite.review import (
    ReviewError,
    apply_reviews,
    load_reviews,
    parse_reviews,
    review_path,
    sample_for_review,
)
from conflictbench.tasks.validation.rules import new_context


@pytest.fixture(scope="module")
def ctx():
    return new_context()


@pytest.fixture(scope="module")
def cases(ctx):
    key = ("libero_goal", 8)
    model = build_model(base_task(*key), load_scene_facts()[key])
    return generate_task_cases(model, operator_entries(), 0, ctx)


def decisions(*rows) -> list:
    return parse_reviews("\n".join(json.dumps(r) for r in rows), "review.jsonl")


@pytest.mark.sim  # LIBERO's base tasks
def test_removed_and_accepted_and_revised(cases, ctx):
    a, b, c = cases[0], cases[1], next(x for x in cases if x.family == "grounding")
    ref = c.witness["referents"][0]["text"]
    new_text = f"please, {c.instruction}"
    out = apply_reviews(
        cases,
        decisions(
            {"case_id": a.case_id, "decision": "removed", "note": "ambiguous"},
            {"case_id": b.case_id, "decision": "accepted", "note": "fine"},
            {"case_id": c.case_id, "decision": "revised", "note": "politer", "instruction": new_text},
        ),
        ctx,
    )
    by_id = {x.case_id: x for x in out}
    assert by_id[a.case_id].status == "removed" and by_id[b.case_id].status == "accepted"
    assert by_id[c.case_id].status == "revised" and by_id[c.case_id].instruction == new_text and ref in new_text
    assert len(out) == len(cases)


@pytest.mark.sim  # LIBERO's base tasks
def test_a_revision_that_breaks_its_witness_is_refused(cases, ctx):
    c = next(x for x in cases if x.family == "grounding")
    with pytest.raises(ReviewError, match="fails validation"):
        apply_reviews(
            cases,
            decisions(
                {"case_id": c.case_id, "decision": "revised", "note": "x", "instruction": "put the bowl somewhere nice"}
            ),
            ctx,
        )


@pytest.mark.sim  # LIBERO's base tasks
def test_a_revision_may_bring_its_own_witness(cases, ctx):
    c = next(x for x in cases if x.family == "grounding" and x.level == "L1")
    text = "put the bowl on the purple trampoline"
    witness = {
        **c.witness,
        "steps": [text],
        "referents": [dict(TRAMPOLINE)],
    }
    out = apply_reviews(
        cases,
        decisions({"case_id": c.case_id, "decision": "revised", "note": "x", "instruction": text, "witness": witness}),
        ctx,
    )
    revised = next(x for x in out if x.case_id == c.case_id).witness
    assert {k: v for k, v in revised.items() if k != "factor_components"} == {
        k: v for k, v in witness.items() if k != "factor_components"
    }
    # which components the factor touches is derived from the reviewer's witness, not copied
    assert revised["factor_components"] == [
        {"step": 1, "kind": "absent destination", "entities": ["plate_1"], "later_steps": []}
    ]


@pytest.mark.sim  # LIBERO's base tasks
def test_a_stale_decision_stops_the_build(cases):
    with pytest.raises(ReviewError, match="not produced by the generator"):
        apply_reviews(cases, decisions({"case_id": "goal08-gro-L1-00000000", "decision": "accepted", "note": ""}))


@pytest.mark.parametrize(
    "row,message",
    [
        ({"case_id": "x", "decision": "maybe", "note": ""}, "field 'decision': 'maybe' is not one of"),
        ({"case_id": "x", "decision": "revised", "note": ""}, "field 'instruction': a revised case needs"),
        ({"decision": "accepted", "note": ""}, "field 'case_id': missing"),
        ({"case_id": "x", "decision": "removed"}, "field 'note': missing"),
    ],
)
def test_malformed_decisions_name_line_and_field(row, message):
    with pytest.raises(ReviewError, match=f"review.jsonl line 2, {message}"):
        decisions({"case_id": "y", "decision": "accepted", "note": ""}, row)


def test_the_shipped_decisions_are_honoured_by_the_shipped_suite():
    """Every usable case of the shipped suite was read and accepted by a named reviewer with a
    reason; removed ones stay reserved; a recheck came from another reader; nothing is pending."""
    from conflictbench.tasks.suite.review import latest

    shipped = {c.case_id: c for c in load_suite().cases}
    reviews = load_reviews()
    assert review_path().exists() and len(reviews) >= len(shipped)
    standing = {d.case_id: d for d in latest(reviews)}
    assert set(standing) == set(shipped)  # every case decided: none pending
    for case_id, case in shipped.items():
        d = standing[case_id]
        assert case.status == d.decision and d.reviewer and d.note.strip()
    assert {"accepted", "removed"} <= {d.decision for d in standing.values()}
    first = {d.case_id: d.reviewer for d in reviews if d.round == 1}
    for d in reviews:
        if d.round > 1:
            assert d.reviewer != first[d.case_id], d.case_id


def test_sampling_is_stratified_deterministic_and_skips_removed():
    suite = load_suite()
    sample = sample_for_review(suite.cases, 3, seed=5)
    assert sample == sample_for_review(suite.cases, 3, seed=5)
    assert sample != sample_for_review(suite.cases, 3, seed=6)
    cells = {}
    for c in sample:
        cells.setdefault((c.family, c.level), []).append(c)
        assert c.status in ("accepted", "revised")
    assert len(cells) == 16 and all(len(v) == 3 for v in cells.values())
    usable = [c for c in suite.cases if c.status in ("accepted", "revised")]
    for (family, level), group in cells.items():
        offered = {c.suite for c in usable if (c.family, c.level) == (family, level)}
        assert len({c.suite for c in group}) == min(3, len(offered)), (family, level)


@pytest.mark.sim  # LIBERO's base tasks
def test_unreviewed_cases_are_pending_when_review_is_required(cases, ctx):
    a, b = cases[0], cases[1]
    out = apply_reviews(
        cases,
        decisions({"case_id": a.case_id, "decision": "accepted", "note": "fine", "reviewer": "r1"}),
        ctx,
        require_review=True,
    )
    status = {c.case_id: c.status for c in out}
    assert status[a.case_id] == "accepted" and status[b.case_id] == "pending"
    assert {c.status for c in out} == {"accepted", "pending"}


@pytest.mark.sim  # LIBERO's base tasks
def test_the_latest_round_decides(cases, ctx):
    a = cases[0]
    rows = [
        {"case_id": a.case_id, "decision": "removed", "note": "questionable: x", "reviewer": "r1", "round": 1},
        {"case_id": a.case_id, "decision": "accepted", "note": "valid: y", "reviewer": "r2", "round": 2},
    ]
    assert next(c for c in apply_reviews(cases, decisions(*rows), ctx) if c.case_id == a.case_id).status == "accepted"
    rows.reverse()  # the order of lines does not matter, the round does
    assert next(c for c in apply_reviews(cases, decisions(*rows), ctx) if c.case_id == a.case_id).status == "accepted"


def test_one_decision_per_case_and_round():
    row = {"case_id": "x", "decision": "accepted", "note": "", "round": 2}
    with pytest.raises(ReviewError, match="'x' was decided in round 2 on line 1"):
        decisions(row, row)
    assert len(decisions(row, {**row, "round": 3})) == 2
    with pytest.raises(ReviewError, match="field 'round': expected a whole number"):
        decisions({**row, "round": 0})
