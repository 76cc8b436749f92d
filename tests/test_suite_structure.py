"""The rules every case meets whatever its family, each shown rejecting a planted case: an
unobservable conflict, a truncated original, a mislabelled step, an ambiguous pronoun, and the same
text twice within a LIBERO suite."""

from __future__ import annotations

import dataclasses

import pytest

from conflictbench.core import ConflictCase
from conflictbench.tasks.validation.rules import new_context, validate_case, validate_cases

pytestmark = pytest.mark.sim  # LIBERO's base tasks

BOWL = "akita_black_bowl_1"


@pytest.fixture(scope="module")
def ctx():
    return new_context()


def _acted_on(i, goals, roles):
    """What step i moves: its goal's object; a pick-up half, the next step's; an added step, the cream cheese."""
    if goals[i]:
        return [g[1] for g in goals[i]]
    if roles[i] == "original" and i + 1 < len(goals) and goals[i + 1]:
        return [g[1] for g in goals[i + 1]]
    return ["cream_cheese_1"]


def case(key, instruction, steps, roles, goals, *, family="instruction", level=None, **witness) -> ConflictCase:
    """A hand-written instruction-family case: a still robot arm in the last step contradicts its goal."""
    last = len(steps)
    goal = next(g for g in reversed(goals) if g)[0]
    witness = {
        "type": "contradiction",
        "steps": steps,
        "step_roles": roles,
        "step_goals": goals,
        "step_entities": [_acted_on(i, goals, roles) for i in range(len(steps))],
        "requirements": [
            {"id": "r1", "step": last, "text": steps[-1], "literal": ["goal", *goal]},
            {"id": "r2", "step": last, "text": "without moving the robot arm", "literal": ["keep", "still", "robot"]},
        ],
        "conflicts": [["r1", "r2", "simultaneous"]],
        **witness,
    }
    from conflictbench.tasks.libero.base_tasks import base_task

    return ConflictCase(
        case_id=f"planted-{abs(hash(instruction)) % 10**8:08d}",
        suite=key[0],
        task_id=key[1],
        base_instruction=base_task(*key).language,
        instruction=instruction,
        family=family,
        level=level or ("L1" if len(steps) == 1 else "L3"),
        factors=("goal vs. a still arm",),
        premise="the arm must move and must not",
        witness=witness,
    )


def test_a_whole_observable_case_passes(ctx):
    good = case(
        ("libero_goal", 8),
        "push the cream cheese aside, then put the bowl on the plate without moving the robot arm",
        ["push the cream cheese aside", "put the bowl on the plate"],
        ["added", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    assert validate_case(good, ctx) == []
    # the same constraint on the placing half of a split pick-and-place is refused (the bowl is in hand)
    split = case(
        ("libero_goal", 8),
        "pick up the bowl, then put it on the plate without moving the robot arm",
        ["pick up the bowl", "put it on the plate"],
        ["original", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    assert any("placing half" in r for r in validate_case(split, ctx)), validate_case(split, ctx)


def test_an_added_step_after_the_original_task_is_rejected(ctx):
    """The episode ends once the bowl is on the plate: a step after it is never reached."""
    late = case(
        ("libero_goal", 8),
        "put the bowl on the plate, then push the cream cheese aside without moving the robot arm",
        ["put the bowl on the plate", "push the cream cheese aside"],
        ["original", "added"],
        [[["on", BOWL, "plate_1"]], []],
    )
    late = dataclasses.replace(
        late,
        witness={
            **late.witness,
            "requirements": [
                {
                    "id": "r1",
                    "step": 2,
                    "text": "push the cream cheese aside",
                    "literal": ["goal", "moved", "cream_cheese_1"],
                },
                {"id": "r2", "step": 2, "text": "without moving the robot arm", "literal": ["keep", "still", "robot"]},
            ],
        },
    )
    reasons = validate_case(late, ctx)
    assert any("come after the original task's first step" in r for r in reasons), reasons
    # The same steps with the added one first are observable.
    early = dataclasses.replace(
        late,
        instruction="push the cream cheese aside without moving the robot arm, then put the bowl on the plate",
        witness={
            **late.witness,
            "steps": ["push the cream cheese aside", "put the bowl on the plate"],
            "step_roles": ["added", "original"],
            "step_goals": [[], [["on", BOWL, "plate_1"]]],
            "step_entities": [["cream_cheese_1"], [BOWL]],
            "requirements": [
                {
                    "id": "r1",
                    "step": 1,
                    "text": "push the cream cheese aside",
                    "literal": ["goal", "moved", "cream_cheese_1"],
                },
                {"id": "r2", "step": 1, "text": "without moving the robot arm", "literal": ["keep", "still", "robot"]},
            ],
        },
    )
    assert validate_case(early, ctx) == []


def test_a_dropped_subgoal_is_rejected(ctx):
    """libero_10 task 3 asks to put the bowl in the drawer AND close it: one step cannot hold both."""
    region = "white_cabinet_1_bottom_region"
    truncated = case(
        ("libero_10", 3),
        "put the black bowl in the bottom drawer of the cabinet without moving the robot arm",
        ["put the black bowl in the bottom drawer of the cabinet"],
        ["original"],
        [[["in", BOWL, region]]],
    )
    reasons = validate_case(truncated, ctx)
    assert any("drops the base task's subgoal" in r and "close" in r for r in reasons), reasons


def test_a_step_that_does_not_name_its_goal_is_rejected(ctx):
    """Claiming the bowl-on-plate goal for a step about the ketchup (the whole-original rule reads the text)."""
    swapped = case(
        ("libero_goal", 8),
        "put the cream cheese on the plate without moving the robot arm",
        ["put the cream cheese on the plate"],
        ["original"],
        [[["on", BOWL, "plate_1"]]],
    )
    reasons = validate_case(swapped, ctx)
    assert any(f"does not name {BOWL}" in r for r in reasons), reasons


def test_a_step_marked_original_that_achieves_nothing_is_rejected(ctx):
    sneaky = case(
        ("libero_goal", 8),
        "push the cream cheese aside, then put the bowl on the plate without moving the robot arm",
        ["push the cream cheese aside", "put the bowl on the plate"],
        ["original", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    reasons = validate_case(sneaky, ctx)
    assert any("marked original but achieves nothing" in r for r in reasons), reasons


@pytest.mark.parametrize(
    "instruction,constraint,needle",
    [
        # "it" after the basket: the basket or the soup?
        (
            "put both the alphabet soup and the tomato sauce in the basket without touching it",
            "without touching it",
            "in a constraint",
        ),
        (
            "put both the alphabet soup and the tomato sauce in the basket without moving its lid",
            "without moving its lid",
            "in a constraint",
        ),
    ],
)
def test_an_ambiguous_pronoun_is_rejected(ctx, instruction, constraint, needle):
    step = "put both the alphabet soup and the tomato sauce in the basket"
    region = "basket_1_contain_region"
    ambiguous = case(
        ("libero_10", 0),
        instruction,
        [step],
        ["original"],
        [[["in", "alphabet_soup_1", region], ["in", "tomato_sauce_1", region]]],
    )
    ambiguous.witness["requirements"][1] = {
        "id": "r2",
        "step": 1,
        "text": constraint,
        "literal": ["keep", "untouched", "alphabet_soup_1"],
    }
    reasons = validate_case(ambiguous, ctx)
    assert any("pronoun" in r and needle in r for r in reasons), reasons


def test_the_same_text_twice_within_a_libero_suite_is_rejected(ctx):
    one = case(
        ("libero_goal", 8),
        "put the bowl on the plate without moving the robot arm",
        ["put the bowl on the plate"],
        ["original"],
        [[["on", BOWL, "plate_1"]]],
    )
    twin = dataclasses.replace(one, case_id="planted-twin")
    assert validate_cases([one], ctx) == []
    assert ("planted-twin", f"same instruction as {one.case_id} within libero_goal") in validate_cases([one, twin], ctx)


def test_a_pronoun_without_a_picked_up_antecedent_is_rejected(ctx):
    """ "push the cream cheese aside, then put it on the plate": "it" is the cream cheese, not the bowl."""
    unclear = case(
        ("libero_goal", 8),
        "push the cream cheese aside, then put it on the plate without moving the robot arm",
        ["push the cream cheese aside", "put it on the plate"],
        ["added", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    reasons = validate_case(unclear, ctx)
    assert any("has no object picked up just before it" in r for r in reasons), reasons


@pytest.mark.parametrize(
    "steps,needle",
    [
        # the stove or the bottle?
        (["lift the wine rack", "fold the wine bottle in half", "place it on the rack"], "opens a step after others"),
        # the milk or the orange juice?
        (["take the bowl with the plate tucked inside the bowl", "put it on the plate"], "opens a step after others"),
        (["pick up the bowl with the plate tucked inside and put it on the plate"], "two things could be meant"),
    ],
)
def test_a_pronoun_after_two_handled_things_is_rejected(ctx, steps, needle):
    text = ", then ".join(steps) + " without moving the robot arm"
    roles = ["added"] * (len(steps) - 1) + ["original"] if len(steps) == 3 else ["original"] * len(steps)
    goals = [[] for _ in steps[:-1]] + [[["on", BOWL, "plate_1"]]]
    unclear = case(("libero_goal", 8), text, steps, roles, goals)
    reasons = validate_case(unclear, ctx)
    assert any(needle in r for r in reasons), reasons


def test_the_base_tasks_own_pronoun_forms_pass(ctx):
    """ "pick up the black bowl between the plate and the ramekin and place it on the plate" (libero_spatial 0)."""
    step = "pick up the black bowl between the plate and the ramekin and place it on the plate"
    good = case(
        ("libero_spatial", 0), step + " without moving the robot arm", [step], ["original"], [[["on", BOWL, "plate_1"]]]
    )
    assert validate_case(good, ctx) == []


def test_no_added_step_moves_a_thing_another_rests_on(ctx):
    """libero_spatial task 5: the second black bowl rests on the cookie box, so "push the cookie box
    aside" would move the bowl too (and could make a later spatial premise true)."""
    from conflictbench.tasks.operators.frames import aux_steps

    model = ctx.model(("libero_spatial", 5))
    assert model.facts.predicate("on", "akita_black_bowl_2", "cookies_1")  # the fact the rule stands on
    moved = {s.objects[0] for s in aux_steps(model) if s.kind == "move_aside"}
    assert "cookies_1" not in moved
    other = ctx.model(("libero_goal", 8))  # nothing rests on its bystanders: they may be moved aside
    assert {s.objects[0] for s in aux_steps(other) if s.kind == "move_aside"} >= {"cream_cheese_1"}
