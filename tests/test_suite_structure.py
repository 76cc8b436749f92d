"""The rules every case meets whatever its family, each shown rejecting a planted case: an
unobservable conflict, a truncated original, a mislabelled step, an ambiguous pronoun, and the same
text twice within a LIBERO suite."""

from __future__ import annotations

import dataclasses

import pytest

from conflictbench.core import ConflictCase
from conflictbench.tasks.validation.factors import factor_components
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
    witness.setdefault("factor_components", factor_components(witness, "contradiction"))
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
    # a split pick-and-place is one step written twice
    split = case(
        ("libero_goal", 8),
        "pick up the bowl, then put it on the plate without moving the robot arm",
        ["pick up the bowl", "put it on the plate"],
        ["original", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    assert any("has no goal of its own" in r for r in validate_case(split, ctx)), validate_case(split, ctx)


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
    late = _recount(late)
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
    assert validate_case(_recount(early), ctx) == []


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


def _recount(c: ConflictCase) -> ConflictCase:
    """The case with its factor_components derived again from its (edited) witness."""
    witness = {**c.witness, "factor_components": factor_components(c.witness, "contradiction")}
    return dataclasses.replace(c, witness=witness)


def test_a_step_marked_original_that_achieves_nothing_is_rejected(ctx):
    sneaky = case(
        ("libero_goal", 8),
        "push the cream cheese aside, then put the bowl on the plate without moving the robot arm",
        ["push the cream cheese aside", "put the bowl on the plate"],
        ["original", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    reasons = validate_case(sneaky, ctx)
    assert any("step 1 has no goal of its own" in r for r in reasons), reasons


# -- suite 2.1: what a step is, and L4's factors (each pattern of suite 2.0's review, planted) -------
def test_a_split_pick_and_place_is_one_step_not_two(ctx):
    """Pattern 1: "grab the bowl, then put it on the plate" is LIBERO's one manipulation written twice;
    labelled L3 it is an L1 case."""
    split = case(
        ("libero_goal", 8),
        "grab the bowl, then put it on the plate without moving the robot arm",
        ["grab the bowl", "put it on the plate"],
        ["original", "original"],
        [[], [["on", BOWL, "plate_1"]]],
    )
    reasons = validate_case(split, ctx)
    assert any("step 1 has no goal of its own: reaching for an object and placing it is one step" in r for r in reasons)
    whole = case(
        ("libero_goal", 8),
        "put the bowl on the plate without moving the robot arm",
        ["put the bowl on the plate"],
        ["original"],
        [[["on", BOWL, "plate_1"]]],
    )
    assert validate_case(whole, ctx) == []


def _two_step_robot_still(second: list) -> ConflictCase:
    """libero_goal 8 as an L4: open the top drawer (added) then the bowl on the plate, each step with
    a constraint; ``second`` is the second step's constraint literal."""
    steps = ["open the top drawer of the cabinet", "put the bowl on the plate"]
    texts = {
        ("keep", "still", "robot"): "without moving the robot arm",
        ("keep", "untouched", BOWL): "without touching the bowl",
    }
    instruction = f"{steps[0]} without moving the robot arm, then {steps[1]} {texts[tuple(second)]}"
    drawer = "wooden_cabinet_1_top_region"
    witness = {
        "requirements": [
            {"id": "r1", "step": 1, "text": steps[0], "literal": ["goal", "open", drawer]},
            {"id": "r2", "step": 1, "text": "without moving the robot arm", "literal": ["keep", "still", "robot"]},
            {"id": "r3", "step": 2, "text": steps[1], "literal": ["goal", "on", BOWL, "plate_1"]},
            {"id": "r4", "step": 2, "text": texts[tuple(second)], "literal": second},
        ],
        "conflicts": [["r1", "r2", "simultaneous"], ["r3", "r4", "simultaneous"]],
        "step_entities": [[drawer, "wooden_cabinet_1"], [BOWL]],
    }
    c = case(
        ("libero_goal", 8),
        instruction,
        steps,
        ["added", "original"],
        [[], [["on", BOWL, "plate_1"]]],
        level="L4",
        **witness,
    )
    return _recount(c)


def test_l4_needs_two_distinct_factors_not_one_constraint_repeated(ctx):
    """Pattern 2: "... without the robot arm moving at all" after each step is one global conflict."""
    repeated = _two_step_robot_still(["keep", "still", "robot"])
    reasons = validate_case(repeated, ctx)
    assert any("L4 needs two distinct factors in different steps" in r for r in reasons), reasons
    distinct = _two_step_robot_still(["keep", "untouched", BOWL])
    assert not [r for r in validate_case(distinct, ctx) if "distinct factors" in r]
    components = distinct.witness["factor_components"]
    assert [(c["step"], c["entities"]) for c in components] == [
        (1, ["robot", "wooden_cabinet_1_top_region"]),
        (2, [BOWL, "plate_1"]),
    ]


def test_an_added_step_may_not_claim_a_far_thing_is_in_the_way(ctx):
    """Pattern 4: "move the cookie box out of the way" where the box stands apart from all the task
    touches; the same step worded without the claim passes."""
    key = ("libero_object", 0)
    model = ctx.model(key)
    far = "salad_dressing_1"
    assert not model.in_the_way(far)
    name = model.name(far)
    task = "pick up the alphabet soup and place it in the basket"
    for wording, claims in ((f"move {name} out of the way", True), (f"pick up {name} and set it back down", False)):
        c = case(
            key,
            f"{wording}, then {task} without moving the robot arm",
            [wording, task],
            ["added", "original"],
            [[], [["in", "alphabet_soup_1", "basket_1_contain_region"]]],
            step_entities=[[far], ["alphabet_soup_1"]],
        )
        reasons = [r for r in validate_case(c, ctx) if "claims" in r]
        assert bool(reasons) == claims, (wording, reasons)
    # where the thing does stand by what the task touches, the claim is allowed
    assert ctx.model(("libero_spatial", 0)).in_the_way("cookies_1")


def test_a_base_task_of_two_manipulations_has_no_single_step_case(ctx):
    """Pattern 5: "put both the soup and the sauce in the basket" is two manipulations: not L1."""
    key = ("libero_object", 0)
    from conflictbench.tasks.libero.base_tasks import all_base_tasks

    task = next(t for t in all_base_tasks() if t.language.startswith("put both"))
    a, b = sorted({atom[1] for atom in task.goal})
    dest = next(iter({atom[2] for atom in task.goal}))
    c = case(
        task.key,
        f"{task.language} without moving the robot arm",
        [task.language],
        ["original"],
        [[list(atom) for atom in task.goal]],
        step_entities=[[a, b]],
    )
    reasons = validate_case(c, ctx)
    assert any("a single-step level on a base task of 2 manipulations" in r for r in reasons), (key, dest, reasons)


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
