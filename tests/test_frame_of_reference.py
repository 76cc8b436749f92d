"""The frame the suite's directions are in: LIBERO's own (the agentview camera's), pinned against
LIBERO's BDDL files, and each claim's ``frame_independent`` flag: whether it is also false read from
the robot's side of the table."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conflictbench.tasks.libero.base_tasks import all_base_tasks
from conflictbench.tasks.scene.facts import DIRECTIONS, Entity, TaskFacts, load_scene_facts
from conflictbench.tasks.validation.rules import new_context
from conflictbench.tasks.validation.spatial import ROBOT_FRAME, frame_independent, referent_combos

pytestmark = pytest.mark.sim  # LIBERO's base tasks


def _region_centre(task, name: str) -> np.ndarray:
    (x0, y0, x1, y1) = task.problem.regions[name].ranges[0]
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2])


def test_libero_says_front_for_plus_x_and_left_for_minus_y():
    """LIBERO's task language is the frame: "push the plate to the front of the stove" has its goal
    region at +x of the stove (towards the camera), and libero_10's "left plate" starts in a region
    LIBERO calls ``plate_left_region``, at -y of the right one (the image's left)."""
    facts = load_scene_facts()
    tasks = {t.language: t for t in all_base_tasks()}
    front = tasks["push the plate to the front of the stove"]
    f = facts[front.key]
    region = f.positions["main_table_stove_front_region"][:, 0]
    assert (region - f.positions["flat_stove_1"][:, 0] > 0.2).all()
    ctx = new_context()
    plates = next(t for t in all_base_tasks() if "left plate" in t.language and "right plate" in t.language)
    model = ctx.model(plates.key)
    left = next(e for e, n in model.names.items() if n == "the left plate")
    right = next(e for e, n in model.names.items() if n == "the right plate")
    f = facts[plates.key]
    assert (f.positions[left][:, 1] < f.positions[right][:, 1] - 0.3).all()
    init = {a[1]: a[2] for a in plates.problem.init if a[0] == "on"}
    assert "left" in init[left] and "right" in init[right]
    assert f.holds("left_of", left, right) == f.states() and not f.holds("right_of", left, right)


def _two(a_xy, b_xy, radius=0.03) -> TaskFacts:
    pos = {"a": np.array([[*a_xy, 0.9]]), "b": np.array([[*b_xy, 0.9]])}
    ents = {k: Entity(k, "thing", "object", radius=radius) for k in pos}
    return TaskFacts("libero_goal", 0, "", "", 1, ents, pos, {}, {}, frozenset({0}))


class _Model:
    def __init__(self, facts):
        self.facts = facts


def test_a_direction_false_in_libero_frame_is_true_from_the_robots_side():
    """Under the lenient reading a direction is false only where the subject lies clearly on the
    OTHER side, which is the claimed side for the robot (its left is the image's right, its front is
    nearer itself): over a grid of placements, no direction claim is frame independent, and things
    side by side (neither clearly left nor right) make no false claim at all. Relations without a
    direction (next to, between, on, in) read the same from both sides."""
    grid = [(x, y) for x in np.linspace(-0.4, 0.4, 17) for y in np.linspace(-0.4, 0.4, 17)]
    false_somewhere = {rel: 0 for rel in DIRECTIONS}
    for a_xy in grid:
        facts = _two(a_xy, (0.0, 0.0))
        for rel in DIRECTIONS:
            if facts.holds(rel, "a", "b"):
                continue  # true (or too close to call) in LIBERO's frame: no case claims it
            false_somewhere[rel] += 1
            assert facts.holds(ROBOT_FRAME[rel], "a", "b") == {0}
            assert frame_independent(_Model(facts), rel, [["a", "b"]], frozenset({0})) is False
        assert frame_independent(_Model(facts), "next_to", [["a", "b"]], frozenset({0})) is True
    assert all(false_somewhere.values()), false_somewhere


def test_the_robots_frame_swaps_both_axes():
    for rel, (axis, sign) in DIRECTIONS.items():
        mirrored_axis, mirrored_sign = DIRECTIONS[ROBOT_FRAME[rel]]
        assert (mirrored_axis, mirrored_sign) == (axis, -sign)


def test_every_shipped_direction_is_false_in_libero_frame_and_flagged_for_the_robots():
    """Over the shipped suite: each directional claim is false in LIBERO's frame, in every state the
    case plays, for every referent its words allow, with the footprints apart; its flag is the robot
    frame's verdict recomputed here, and the case's flag is whether all its claims hold."""
    from conflictbench.tasks.suite.file import load_suite

    ctx = new_context()
    counted = {True: 0, False: 0}
    for case in load_suite(None).cases:
        if case.family != "spatial" or case.status == "removed":
            continue
        model = ctx.model((case.suite, case.task_id))
        states = frozenset(case.init_states) if case.init_states else model.facts.states()
        flags = []
        for r in case.witness["relations"]:
            groups = [r["subject"]["entities"], *(lm["entities"] for lm in r["landmarks"])]
            combos = referent_combos(groups)
            for combo in combos:
                assert not model.facts.holds(r["relation"], *combo) & states, (case.case_id, r["relation"], combo)
            if r["relation"] in DIRECTIONS:
                for a, b in combos:
                    assert model.facts.footprint_gap(r["relation"], a, b)[sorted(states)].min() >= 0.01 - 1e-9
            expected = frame_independent(model, r["relation"], combos, states)
            assert r["frame_independent"] is expected, case.case_id
            flags.append(expected)
        assert case.witness["frame_independent"] is all(flags), case.case_id
        counted[all(flags)] += 1
    assert counted[True] > 0 and counted[False] > 0, counted


def test_a_wrong_frame_flag_is_rejected():
    from conflictbench.tasks.suite.file import load_suite
    from conflictbench.tasks.validation.rules import validate_case

    ctx = new_context()
    case = next(
        c
        for c in load_suite(None).cases
        if c.family == "spatial" and c.status != "removed" and c.witness["relations"][0]["relation"] in DIRECTIONS
    )
    relations = [dict(r) for r in case.witness["relations"]]
    relations[0]["frame_independent"] = not relations[0]["frame_independent"]
    flipped = dataclasses.replace(case, witness={**case.witness, "relations": relations})
    assert any("witness frame_independent" in r for r in validate_case(flipped, ctx))
