"""Instruction family (suite 2.0): a contradiction holds under every order of execution.

The rules of :mod:`conflictbench.tasks.operators.contradictions` are checked on scene facts alone
(no simulator); the validator is checked with one planted bad case per rule, and the operator's
drafts with what they must and must never contain (LIBERO base tasks: ``sim``)."""

from __future__ import annotations

import dataclasses
import random
from collections import Counter

import pytest
from testing_support import rejected

from conflictbench.tasks.operators.contradictions import explain, why_not
from conflictbench.tasks.scene.facts import load_scene_facts
from conflictbench.tasks.validation.factors import factor_components

BOWL_ON_PLATE = ("libero_goal", 8)  # put the bowl on the plate
MIDDLE_DRAWER = ("libero_goal", 0)  # open the middle drawer of the cabinet
STOVE = ("libero_goal", 7)  # turn on the stove
TWO_BOWLS = ("libero_spatial", 0)  # pick up the black bowl between the plate and the ramekin ...
BOWL = "akita_black_bowl_1"
ON_PLATE = ["goal", "on", BOWL, "plate_1"]
OPEN_MIDDLE = ["goal", "open", "wooden_cabinet_1_middle_region"]


def _explain(key, a, b):
    facts = load_scene_facts()[key]
    return explain(a, b, facts, facts.states()), why_not(a, b, facts, facts.states())


# -- the rules, on scene facts --------------------------------------------------------------------
@pytest.mark.parametrize(
    "key, constraint",
    [
        (BOWL_ON_PLATE, ["keep", "still", BOWL]),
        (BOWL_ON_PLATE, ["keep", "untouched", BOWL]),
        (BOWL_ON_PLATE, ["keep", "still", "robot"]),
        (MIDDLE_DRAWER, ["keep", "close", "wooden_cabinet_1_middle_region"]),
        (MIDDLE_DRAWER, ["keep", "untouched", "wooden_cabinet_1_middle_region"]),
        (STOVE, ["keep", "turnoff", "flat_stove_1"]),
        (STOVE, ["keep", "untouched", "flat_stove_1"]),
    ],
)
def test_a_constraint_throughout_the_step_contradicts_its_goal(key, constraint):
    goal = {BOWL_ON_PLATE: ON_PLATE, MIDDLE_DRAWER: OPEN_MIDDLE, STOVE: ["goal", "turnon", "flat_stove_1"]}[key]
    found, _ = _explain(key, goal, constraint)
    assert found is not None and found[0] == "simultaneous"
    assert _explain(key, constraint, goal)[0] == found  # the order of the pair does not matter


@pytest.mark.parametrize(
    "key, a, b, reason",
    [
        # do it, then undo it
        (BOWL_ON_PLATE, ON_PLATE, ["avoid", "on", BOWL, "plate_1"], "satisfiable by doing"),
        (MIDDLE_DRAWER, OPEN_MIDDLE, ["end", "close", "wooden_cabinet_1_middle_region"], "satisfiable by doing"),
        (STOVE, ["goal", "turnon", "flat_stove_1"], ["end", "turnoff", "flat_stove_1"], "satisfiable by doing"),
        # a constraint on something the step need not touch: the plate, the drawer's cabinet
        (BOWL_ON_PLATE, ON_PLATE, ["keep", "untouched", "plate_1"], "need not touch"),
        (MIDDLE_DRAWER, OPEN_MIDDLE, ["keep", "untouched", "wooden_cabinet_1"], "need not touch"),
        (BOWL_ON_PLATE, ON_PLATE, ["keep", "still", "plate_1"], "need not touch"),
        # a bowl can be scooped
        (BOWL_ON_PLATE, ["do", "lift", BOWL], ["keep", "ungrasped", BOWL], "scooped"),
    ],
)
def test_pairs_some_order_satisfies_are_not_contradictions(key, a, b, reason):
    found, why = _explain(key, a, b)
    assert found is None
    assert reason in why


def test_two_end_conditions_no_final_state_meets_are_final_states():
    drawer = "wooden_cabinet_1_middle_region"
    assert _explain(MIDDLE_DRAWER, ["end", "open", drawer], ["end", "close", drawer])[0][0] == "final_states"
    assert _explain(BOWL_ON_PLATE, ["end", "on", BOWL, "plate_1"], ["avoid", "on", BOWL, "plate_1"])[0][0] == (
        "final_states"
    )
    # two end conditions that one final state meets
    assert _explain(MIDDLE_DRAWER, ["end", "open", drawer], ["end", "open", drawer])[0] is None


# -- the validator: one planted case per rule ------------------------------------------------------
@pytest.fixture(scope="module")
def ctx():
    from conflictbench.tasks.validation.rules import new_context

    return new_context()


def _model(key, ctx):
    return ctx.model(key)


def _drafts(key, level, ctx, seed=0, limit=60):
    from conflictbench.tasks.operators.instruction import generate

    out = []
    for d in generate(_model(key, ctx), level, random.Random(seed)):
        out.append(d)
        if len(out) >= limit:
            break
    return out


def _case(key, level, ctx, where=lambda d: True):
    from conflictbench.tasks.libero.base_tasks import base_task
    from conflictbench.tasks.suite.build import _to_case

    return _to_case(base_task(*key), next(d for d in _drafts(key, level, ctx) if where(d)))


def _recount(case):
    """The case with its factor_components derived again from its edited witness."""
    witness = {**case.witness, "factor_components": factor_components(case.witness, "contradiction")}
    return dataclasses.replace(case, witness=witness)


def _planted(case, constraint_text, literal, mode="simultaneous"):
    """The case's step goal with a different constraint, written into the instruction."""
    goal = case.witness["requirements"][0]
    body = case.witness["steps"][0]
    planted = dataclasses.replace(
        case,
        instruction=f"{body} {constraint_text}",
        witness={
            **case.witness,
            "requirements": [goal, {"id": "r9", "step": 1, "text": constraint_text, "literal": literal}],
            "conflicts": [[goal["id"], "r9", mode]],
        },
    )
    return _recount(planted)


def _reasons(case, ctx):
    from conflictbench.tasks.validation.rules import validate_case

    return validate_case(case, ctx)


@pytest.mark.sim
def test_the_unplanted_cases_are_accepted(ctx):
    case = _case(BOWL_ON_PLATE, "L1", ctx)
    assert _reasons(case, ctx) == []
    assert _reasons(_planted(case, "without touching the bowl", ["keep", "untouched", BOWL]), ctx) == []


@pytest.mark.sim
@pytest.mark.parametrize(
    "task, text, literal, reason",
    [
        pytest.param(BOWL_ON_PLATE, "making sure the bowl is not on the plate at the end",
                     ["avoid", "on", BOWL, "plate_1"], "satisfiable by doing", id="do-it-then-undo-it"),
        pytest.param(STOVE, "and make sure the stove is off at the end", ["end", "turnoff", "flat_stove_1"],
                     "satisfiable by doing", id="do-it-then-undo-it-stove"),
        pytest.param(BOWL_ON_PLATE, "without touching it", ["keep", "untouched", BOWL], "uses a pronoun",
                     id="a-pronoun"),
        pytest.param(BOWL_ON_PLATE, "without touching the plate", ["keep", "untouched", "plate_1"],
                     "need not touch", id="another-entity"),
        pytest.param(MIDDLE_DRAWER, "without touching the cabinet", ["keep", "untouched", "wooden_cabinet_1"],
                     "need not touch", id="another-entity-cabinet"),
        pytest.param(BOWL_ON_PLATE, "without grasping the bowl", ["keep", "ungrasped", BOWL], "scooped",
                     id="not-grasping"),
    ],
)  # fmt: skip
def test_a_planted_constraint_the_rules_refuse_is_rejected(task, text, literal, reason, ctx):
    rejected(_reasons(_planted(_case(task, "L1", ctx), text, literal), ctx), reason)


@pytest.mark.sim
def test_the_mode_must_be_given_and_right(ctx):
    case = _case(BOWL_ON_PLATE, "L1", ctx)
    pair = case.witness["conflicts"][0]
    rejected(
        _reasons(dataclasses.replace(case, witness={**case.witness, "conflicts": [pair[:2]]}), ctx), "must say its mode"
    )
    wrong = dataclasses.replace(case, witness={**case.witness, "conflicts": [[*pair[:2], "final_states"]]})
    rejected(_reasons(wrong, ctx), "is simultaneous, not final_states")


@pytest.mark.sim
def test_an_ambiguous_name_is_rejected(ctx):
    # two black bowls: "the black bowl" could be either
    case = _case(TWO_BOWLS, "L1", ctx)
    planted = _planted(case, "without touching the black bowl", ["keep", "untouched", BOWL])
    rejected(_reasons(planted, ctx), "unambiguously")


@pytest.mark.sim
def test_a_repeated_constraint_is_filler(ctx):
    case = _case(BOWL_ON_PLATE, "L2", ctx)
    goal, first = case.witness["requirements"][:2]
    twin = {**first, "id": "r9", "text": first["text"]}
    planted = dataclasses.replace(
        case,
        witness={
            **case.witness,
            "requirements": [goal, first, twin],
            "conflicts": [[goal["id"], first["id"], "simultaneous"], [goal["id"], "r9", "simultaneous"]],
        },
    )
    rejected(_reasons(planted, ctx), "repeats the constraint")


@pytest.mark.sim
def test_a_goal_the_step_does_not_ask_for_is_rejected(ctx):
    case = _case(BOWL_ON_PLATE, "L1", ctx)
    reqs = [dict(r) for r in case.witness["requirements"]]
    reqs[0]["literal"] = ["goal", "in", BOWL, "plate_1"]
    rejected(
        _reasons(dataclasses.replace(case, witness={**case.witness, "requirements": reqs}), ctx), "is not what step 1"
    )


@pytest.mark.sim
def test_l4_needs_factors_in_two_steps(ctx):
    case = _case(BOWL_ON_PLATE, "L3", ctx)
    goal, constraint = case.witness["requirements"][:2]
    other = {**constraint, "id": "r9", "text": "and never touch the bowl", "literal": ["keep", "untouched", BOWL]}
    if constraint["literal"] == other["literal"]:
        other["literal"], other["text"] = ["keep", "still", "robot"], "and keep the robot arm completely still"
    planted = dataclasses.replace(
        case,
        level="L4",
        instruction=f"{case.instruction} {other['text']}",
        witness={
            **case.witness,
            "requirements": [goal, constraint, other],
            "conflicts": [[goal["id"], constraint["id"], "simultaneous"], [goal["id"], "r9", "simultaneous"]],
        },
    )
    rejected(_reasons(planted, ctx), "does not match the witness")


def _moved_constraint(case, step, literal=None):
    reqs = [dict(r) for r in case.witness["requirements"]]
    constraint = next(r for r in reqs if r["literal"][0] == "keep")
    constraint["step"] = step
    if literal:
        constraint["literal"] = literal
    return _recount(dataclasses.replace(case, witness={**case.witness, "requirements": reqs}))


@pytest.mark.sim
def test_untouched_on_a_pushing_step_is_rejected(ctx):
    def pushed_still(d):
        first = d.witness["steps"][0]
        return first.startswith(("push", "slide", "move")) and any(
            r["step"] == 1 and r["literal"][:2] == ["keep", "still"] and r["literal"][2] != "robot"
            for r in d.witness["requirements"]
        )

    from conflictbench.tasks.libero.base_tasks import base_task
    from conflictbench.tasks.suite.build import _to_case

    key = ("libero_spatial", 0)  # the cookie box stands by the bowl: "push the cookie box aside" is true
    case = _to_case(base_task(*key), next(d for d in _drafts(key, "L3", ctx, limit=400) if pushed_still(d)))
    assert _reasons(case, ctx) == []  # keeping the pushed thing still contradicts pushing it
    literal = next(r["literal"] for r in case.witness["requirements"] if r["literal"][0] == "keep")
    rejected(_reasons(_moved_constraint(case, 1, ["keep", "untouched", literal[2]]), ctx), "pushing step")


# -- the operator ---------------------------------------------------------------------------------
TASKS = [BOWL_ON_PLATE, MIDDLE_DRAWER, STOVE, TWO_BOWLS, ("libero_10", 0), ("libero_10", 3), ("libero_10", 9)]


@pytest.mark.sim
@pytest.mark.parametrize("level", ["L1", "L2", "L3", "L4"])
def test_drafts_are_valid_simultaneous_and_about_the_steps_own_things(level, ctx):
    from conflictbench.tasks.libero.base_tasks import base_task
    from conflictbench.tasks.suite.build import _to_case

    checked = 0
    for key in TASKS:
        if level in ("L1", "L2") and len(_model(key, ctx).steps) > 1:
            assert _drafts(key, level, ctx) == []  # no single step asks for a two-step task whole
            continue
        for d in _drafts(key, level, ctx, limit=30):
            assert _reasons(_to_case(base_task(*key), d), ctx) == [], d.instruction
            reqs = {r["id"]: r for r in d.witness["requirements"]}
            for goal_id, constraint_id, mode in d.witness["conflicts"]:
                goal, constraint = reqs[goal_id]["literal"], reqs[constraint_id]["literal"]
                assert mode == "simultaneous" and constraint[0] == "keep"
                assert constraint[2] in ("robot", goal[2])  # the moved or operated thing itself, or the arm
                assert constraint[1] != "ungrasped"
                step = reqs[constraint_id]["step"]
                body = d.witness["steps"][step - 1]
                assert not (step >= 2 and body.startswith(("place it", "put it", "set it"))), d.instruction
                if constraint[1] == "untouched":
                    assert not body.startswith(("push", "slide", "shove", "move")), d.instruction
                if goal[:2] == ["do", "lift"] and constraint[2] != "robot":
                    assert body.startswith(("pick up", "lift")), d.instruction
            steps = Counter(reqs[c[1]]["step"] for c in d.witness["conflicts"])
            if level == "L2":
                assert len(d.witness["conflicts"]) == 2 and len(steps) == 1
            if level == "L4":
                assert len(steps) >= 2
            checked += 1
    assert checked >= 20


@pytest.mark.sim
def test_phrasings_vary_and_instructions_do_not_repeat(ctx):
    texts = [d.instruction for d in _drafts(BOWL_ON_PLATE, "L1", ctx, limit=60)]
    constraints = {t.removeprefix("put the bowl on the plate").split(" the bowl")[0] for t in texts}
    assert len(set(texts)) >= 0.8 * len(texts)
    assert len(constraints) >= 6
    for t in texts:
        assert t == t.lower() and not t.endswith(".")
