"""The physical family: every draft asks the whole original task with an impossible manner,
participant or added step, and the validator rejects each defect of the old suite."""

from __future__ import annotations

import dataclasses
import random

import pytest
from testing_support import rejected

from conflictbench.tasks.libero.base_tasks import base_task
from conflictbench.tasks.operators import physical
from conflictbench.tasks.scene.facts import load_scene_facts
from conflictbench.tasks.scene.task_model import build_model
from conflictbench.tasks.suite.build import _to_case
from conflictbench.tasks.validation.physical import HOLDING_ONLY, skeleton, suite_problems
from conflictbench.tasks.validation.rules import new_context, validate_case

pytestmark = pytest.mark.sim  # LIBERO's base tasks

TASKS = [("libero_spatial", 0), ("libero_object", 4), ("libero_goal", 8), ("libero_goal", 3), ("libero_10", 3)]

ONLY_CONTAINMENT = {("libero_object", 4)}
"""One-step tasks whose only violation is their own object as a holder: no second one for L2."""


@pytest.fixture(scope="module")
def ctx():
    return new_context()


def model(key):
    return build_model(base_task(*key), load_scene_facts()[key])


def cases(key, level, seed=0):
    task = base_task(*key)
    return [_to_case(task, d) for d in physical.generate(model(key), level, random.Random(seed))]


def one(key, level, where=lambda c: True):
    return next(c for c in cases(key, level) if where(c))


def with_violations(case, violations):
    return dataclasses.replace(case, witness={**case.witness, "violations": violations})


@pytest.mark.parametrize("key", TASKS)
@pytest.mark.parametrize("level", ["L1", "L2", "L3", "L4"])
def test_drafts_validate_and_keep_the_original_object_and_destination(ctx, key, level):
    drafts = cases(key, level)
    if level in ("L1", "L2") and len(model(key).steps) > 1:
        assert drafts == []
        return
    if level == "L2" and key in ONLY_CONTAINMENT:
        assert drafts == []
        return
    assert drafts
    for case in drafts:
        assert validate_case(case, ctx) == [], case.instruction
        assert case.instruction == case.instruction.lower() and not case.instruction.endswith(".")


def test_the_old_replaced_object_is_rejected(ctx):
    good = one(("libero_goal", 8), "L1")
    planted = dataclasses.replace(
        good,
        instruction="set the table on the plate",
        witness={**good.witness, "steps": ["set the table on the plate"]},
    )
    planted = with_violations(
        planted, [{"step": 1, "kind": "fixed", "needs": "graspable", "entity": "main_table", "text": "the table"}]
    )
    rejected(validate_case(planted, ctx), "does not name akita_black_bowl_1")


def test_a_violation_needs_a_known_kind_matching_its_affordance(ctx):
    good = one(("libero_goal", 8), "L1", lambda c: c.witness["violations"][0]["kind"] == "rigidity")
    v = good.witness["violations"][0]
    rejected(validate_case(with_violations(good, [{**v, "kind": "magic"}]), ctx), "unknown kind")
    rejected(validate_case(with_violations(good, [{**v, "kind": "switch"}]), ctx), "is about turnable")


def test_undecided_or_held_affordances_are_not_violations(ctx):
    good = one(("libero_goal", 8), "L1", lambda c: c.witness["violations"][0]["kind"] == "rigidity")
    v = good.witness["violations"][0]
    # the bowl has pourable null (undecided) and is a container (true): neither is a violation
    rejected(
        validate_case(with_violations(good, [{**v, "kind": "pouring", "needs": "pourable"}]), ctx),
        "does not plainly lack",
    )
    rejected(
        validate_case(with_violations(good, [{**v, "kind": "containment", "needs": "container"}]), ctx),
        "does not plainly lack",
    )
    rejected(validate_case(with_violations(good, [{**v, "entity": "basket_1"}]), ctx), "is not in the scene")
    rejected(
        validate_case(with_violations(good, [{**v, "text": "fold the plate in half"}]), ctx),
        "is not in the instruction",
    )


def test_size_comes_from_the_table_sizes():
    from conflictbench.tasks.validation.physical import _denied

    m = model(("libero_10", 5))
    present = set(m.problem.objects) | set(m.problem.fixtures)
    v = {"kind": "size", "needs": "fits_in", "entity": "black_book_1", "holder": "white_yellow_mug_1"}
    assert _denied(m, {**v, "text": "put the black book inside the yellow and white mug"}, present) == []
    swapped = {**v, "entity": "white_yellow_mug_1", "holder": "black_book_1"}  # a mug is smaller than a book
    assert any("may fit inside" in r for r in _denied(m, {**swapped, "text": "x"}, present))


def test_level_shapes(ctx):
    l2 = one(("libero_goal", 8), "L2")
    first = l2.witness["violations"][0]
    rejected(validate_case(with_violations(l2, [first, dict(first)]), ctx), "is repeated")
    l4 = one(("libero_goal", 8), "L4")
    v1, v2 = l4.witness["violations"][:2]
    rejected(validate_case(with_violations(l4, [v1, {**v2, "step": v1["step"]}]), ctx), "at least two different steps")
    l2_split = with_violations(l2, [first, {**l2.witness["violations"][1], "step": 2}])
    assert validate_case(l2_split, ctx)


def test_l3_has_one_violation_and_added_steps_come_first(ctx):
    for case in cases(("libero_goal", 8), "L3"):
        assert len(case.witness["violations"]) == 1
        roles = case.witness["step_roles"]
        assert "added" not in roles[roles.index("original") :]


def test_suite_problems_catch_monotone_cells_and_repeated_text():
    key = ("libero_goal", 8)
    models = {key: model(key)}
    l1 = cases(key, "L1")
    rigid = [c for c in l1 if c.witness["violations"][0]["kind"] == "rigidity"][:1]
    assert rigid
    same = [dataclasses.replace(rigid[0], case_id=f"c{i}") for i in range(4)]
    reasons = [r for _, r in suite_problems(same, models)]
    assert any("kind(s)" in r for r in reasons)
    assert any("skeleton" in r for r in reasons)
    assert any("same text" in r for r in reasons)
    assert skeleton(rigid[0], models[key]).count("<e>") == 2


def test_the_built_cells_are_varied():
    """Kinds and skeletons over a handful of tasks already spread out."""
    keys = [("libero_spatial", 0), ("libero_object", 2), ("libero_goal", 8), ("libero_goal", 9)]
    models = {k: model(k) for k in keys}
    every = [c for k in keys for c in cases(k, "L3")]
    kinds = {v["kind"] for c in every for v in c.witness["violations"]}
    assert kinds >= {"rigidity", "switch", "articulation", "fixed"}
    pool = [c for k in keys for c in cases(k, "L3")[:6]]
    assert not [r for _, r in suite_problems(pool, models) if "skeleton" in r]


def replaced_text(case, old, new, violations):
    """The case with ``old`` written as ``new`` in its instruction and steps."""
    steps = [step.replace(old, new) for step in case.witness["steps"]]
    case = dataclasses.replace(case, instruction=case.instruction.replace(old, new))
    return dataclasses.replace(case, witness={**case.witness, "steps": steps, "violations": violations})


@pytest.mark.parametrize("key", TASKS)
def test_no_support_and_no_holding_only_fixtures_are_generated(key):
    for level in ("L1", "L2", "L3", "L4"):
        for case in cases(key, level):
            for v in case.witness["violations"]:
                assert v["kind"] != "support", case.instruction
                assert v["kind"] != "fixed" or not HOLDING_ONLY.search(v["text"]), case.instruction


def test_support_violations_are_rejected_as_disputable(ctx):
    """'the plate standing on top of the wine bottle': a plate can balance on a bottle mouth."""
    good = one(("libero_goal", 8), "L1", lambda c: c.witness["violations"][0]["kind"] == "rigidity")
    v = good.witness["violations"][0]
    planted = {**v, "kind": "support", "needs": "support", "entity": "wine_bottle_1"}
    rejected(validate_case(with_violations(good, [planted]), ctx), "is disputable")


def test_a_fixture_only_held_is_rejected(ctx):
    """'open the drawer while holding the cabinet': gripping a fixture in place is possible."""
    good = one(("libero_goal", 0), "L1", lambda c: c.witness["violations"][0]["kind"] == "fixed")
    assert validate_case(good, ctx) == []
    v = good.witness["violations"][0]
    held = v["text"].replace("lift", "hold").replace("pick up", "hold")
    planted = replaced_text(good, v["text"], held, [{**v, "text": held}])
    rejected(validate_case(planted, ctx), "only holds or touches")


@pytest.mark.parametrize(
    "joined",
    [
        "together with the wooden cabinet",
        "while carrying the wooden cabinet",
        "with the milk packed inside the ramekin",
    ],
)
def test_a_participant_joined_after_the_goal_is_rejected(ctx, joined):
    """'put the bowl on the plate together with the cabinet': the goal is met before the cabinet."""
    good = one(("libero_spatial", 1), "L1")
    body = good.witness["steps"][0]
    planted = dataclasses.replace(good, instruction=f"{good.instruction} {joined}")
    v = {"step": 1, "kind": "fixed", "needs": "graspable", "entity": "wooden_cabinet_1", "text": joined}
    rejected(validate_case(with_violations(planted, [v]), ctx), "joined participant")
    assert body in planted.instruction


def test_an_added_participant_of_a_goal_step_is_rejected(ctx):
    """'open both the middle drawer and the plate': the drawer opens, the episode ends."""
    good = one(("libero_goal", 0), "L1")
    v = {**good.witness["violations"][0], "entity": "plate_1", "kind": "articulation", "needs": "openable"}
    rejected(validate_case(with_violations(good, [v]), ctx), "added participant")


def test_pouring_and_boxes_as_holders_are_rejected(ctx):
    good = one(("libero_object", 6), "L1")
    v = good.witness["violations"][0]
    rejected(
        validate_case(with_violations(good, [{**v, "kind": "pouring", "needs": "pourable"}]), ctx), "is disputable"
    )
    boxed = {**v, "kind": "containment", "needs": "container", "entity": "butter_1"}
    rejected(validate_case(with_violations(good, [boxed]), ctx), "invites opening")


def test_a_too_small_holder_inside_an_original_step_is_rejected(ctx):
    """'squeeze the black bowl into the ramekin and set the black bowl down on the plate' is two
    placements (suite 2.0's readers): a size violation is an added step of its own, never a manner."""
    good = one(("libero_spatial", 8), "L1", lambda c: c.witness["steps"][0].startswith("pick up"))
    body = good.witness["steps"][0]
    verb = body.split(" the ")[0]
    squeezed = body.replace(verb, "squeeze", 1).replace(" and ", " into the ramekin and ", 1)
    size = {
        "step": 1,
        "kind": "size",
        "needs": "fits_in",
        "entity": "akita_black_bowl_1",
        "holder": "glazed_rim_porcelain_ramekin_1",
        "text": squeezed.split(" and ")[0],
    }
    rejected(validate_case(replaced_text(good, body, squeezed, [size]), ctx), "a step of its own, not a manner")


def physical_kinds(case):
    return {v["kind"] for v in case.witness["violations"]}


def test_a_box_is_never_a_size_holder():
    """No holder with 'box', 'carton', 'bag' or 'package' in its name: it invites opening or stretching."""
    from conflictbench.tasks.validation.physical import _denied

    m = model(("libero_spatial", 8))
    holder = "glazed_rim_porcelain_ramekin_1"
    present = set(m.problem.objects) | set(m.problem.fixtures)
    v = {"kind": "size", "needs": "fits_in", "entity": "akita_black_bowl_1", "holder": holder}
    v["text"] = "squeeze the black bowl into the ramekin"
    assert _denied(m, v, present) == []
    m.names[holder] = "the ramekin box"
    assert any("box, carton" in r for r in _denied(m, v, present))


def grasps_again(case, ctx):
    return [r for r in validate_case(case, ctx) if "grasps" in r]


@pytest.mark.parametrize("key", TASKS)
def test_no_step_grasps_what_it_or_the_step_before_grasped(ctx, key):
    """'lift the butter, then pick up the butter, switch on the butter ...' repeats the pick-up."""
    for level in ("L1", "L2", "L3", "L4"):
        for case in cases(key, level):
            assert grasps_again(case, ctx) == [], case.instruction


def test_a_repeated_grasp_is_rejected(ctx):
    key = ("libero_spatial", 0)
    good = one(key, "L1", lambda c: c.witness["steps"][0].startswith("pick up"))
    body = good.witness["steps"][0]
    twice = body.replace(", switch on the black bowl", ", switch on the black bowl, lift the black bowl")
    assert twice != body
    rejected(validate_case(replaced_text(good, body, twice, good.witness["violations"]), ctx), "twice")


def test_a_twinned_bowl_is_named_in_full_in_its_violation(ctx):
    """libero_spatial has two identical black bowls: "pick up the black bowl between the plate and the
    ramekin, switch on the black bowl ..." could mean either (suite 2.1's audit)."""
    key = ("libero_spatial", 0)
    full = "the black bowl between the plate and the ramekin"
    good = one(key, "L1", lambda c: c.witness["violations"][0]["kind"] == "switch")
    v = good.witness["violations"][0]
    assert full in v["text"] and validate_case(good, ctx) == []
    short = v["text"].replace(full, "the black bowl")
    rejected(
        validate_case(replaced_text(good, v["text"], short, [{**v, "text": short}]), ctx), "its identical twin shares"
    )
