"""The spatial family: what its operator writes is valid, and each of its validator's rules rejects
a planted case that breaks it (a stale relation, a margin a camera cannot see, a contradiction in
words, an absurd holder, a claim made twice, a margin the witness misstates)."""

from __future__ import annotations

import dataclasses
import random

import numpy as np
import pytest
from testing_support import rejected

from conflictbench.core import LEVELS
from conflictbench.tasks.libero.base_tasks import base_task
from conflictbench.tasks.operators import spatial
from conflictbench.tasks.scene.facts import DIRECTIONS, FOOTPRINT_GAP, load_scene_facts
from conflictbench.tasks.scene.task_model import build_model
from conflictbench.tasks.suite.build import _to_case
from conflictbench.tasks.validation.rules import new_context, validate_case
from conflictbench.tasks.validation.spatial import check_relation

pytestmark = pytest.mark.sim  # the cases are built from LIBERO's base tasks

TASKS = [("libero_spatial", 0), ("libero_object", 4), ("libero_goal", 8), ("libero_10", 4), ("libero_10", 9)]


@pytest.fixture(scope="module")
def ctx():
    return new_context()


def model(key):
    return build_model(base_task(*key), load_scene_facts()[key])


def cases(key, level, limit=30):
    out = []
    for d in spatial.generate(model(key), level, random.Random(0)):
        out.append(_to_case(base_task(*key), d))
        if len(out) >= limit:
            break
    return out


def find(key, level, where):
    return next(c for c in cases(key, level, limit=400) if where(c))


def reasons(case, m=None):
    m = m or model((case.suite, case.task_id))
    states = m.facts.states() if case.init_states is None else frozenset(case.init_states)
    return check_relation(case, m, states)


def with_relation(case, index=0, **changes):
    rels = [dict(r) for r in case.witness["relations"]]
    rels[index].update(changes)
    return dataclasses.replace(case, witness={**case.witness, "relations": rels})


# -- what the operator writes -----------------------------------------------------------------------------
@pytest.mark.parametrize("level", LEVELS)
def test_drafts_pass_every_rule_and_directions_carry_their_margin(level, ctx):
    produced = 0
    for key in TASKS:
        for case in cases(key, level, limit=10):
            assert validate_case(case, ctx) == [], (case.instruction, validate_case(case, ctx))
            for r in case.witness["relations"]:
                if r["relation"] in ("left_of", "right_of", "in_front_of", "behind"):
                    assert r["margin_m"] >= FOOTPRINT_GAP  # the footprints' gap along the axis
            produced += 1
    assert produced >= 10


def test_no_relation_is_about_what_an_earlier_step_moved():
    for key in TASKS:
        for level in ("L3", "L4"):
            for case in cases(key, level, limit=60):
                acted = case.witness["step_entities"]
                for r in case.witness["relations"]:
                    earlier = {e for s in acted[: r["step"] - 1] for e in s}
                    named = set(r["subject"]["entities"]) | {e for lm in r["landmarks"] for e in lm["entities"]}
                    assert not named & earlier, (case.instruction, r)


def test_an_added_step_never_moves_what_the_base_name_describes_by():
    # "slide the ramekin aside, then pick up the black bowl between the plate and the ramekin ..."
    for case in cases(("libero_spatial", 0), "L3", limit=400):
        if case.witness["step_roles"][0] == "added":
            moved = set(case.witness["step_entities"][0])
            assert not moved & {"glazed_rim_porcelain_ramekin_1", "plate_1"}, case.instruction


# -- planted cases, one per rule --------------------------------------------------------------------------
def test_a_landmark_an_earlier_step_moves_is_rejected():
    case = find(("libero_object", 4), "L3", lambda c: c.witness["step_roles"][0] == "added")
    moved = case.witness["step_entities"][0][0]
    phrase = moved.rsplit("_", 1)[0].replace("_", " ")
    text = f"the basket next to the {phrase}"
    planted = dataclasses.replace(
        case,
        instruction=f"{case.witness['steps'][0]}, then put the ketchup in {text}",
        witness={
            **case.witness,
            "steps": [case.witness["steps"][0], f"put the ketchup in {text}"],
            "relations": [
                {
                    "step": 2,
                    "text": text,
                    "relation": "next_to",
                    "subject": {"phrase": "basket", "entities": ["basket_1", "basket_1_contain_region"]},
                    "landmarks": [{"phrase": phrase, "entities": [moved]}],
                }
            ],
        },
    )
    rejected(reasons(planted), "which an earlier step moves or operates")


def test_a_landmark_the_same_step_moves_is_rejected():
    case = find(("libero_object", 4), "L1", lambda c: c.witness["relations"][0]["subject"]["phrase"] == "basket")
    text = "the basket that is next to the ketchup"
    planted = with_relation(
        dataclasses.replace(case, instruction=f"put the ketchup in {text}"),
        text=text,
        relation="next_to",
        landmarks=[{"phrase": "ketchup", "entities": ["ketchup_1"]}],
    )
    planted = dataclasses.replace(
        planted, witness={**planted.witness, "steps": [planted.instruction], "step_entities": [["ketchup_1"]]}
    )
    rejected(reasons(planted), "which that same step moves, as its landmark")


def test_a_direction_false_by_less_than_the_camera_margin_is_rejected():
    key = ("libero_object", 4)
    case = find(key, "L1", lambda c: c.witness["relations"][0]["relation"] in ("left_of", "right_of"))
    r = case.witness["relations"][0]
    m = model(key)
    subject, landmark = r["subject"]["entities"][0], r["landmarks"][0]["entities"][0]
    # move the subject so that it lies only 4 cm past the landmark's centre, on the other side
    sign = -1.0 if r["relation"] == "left_of" else 1.0  # right_of is false where the subject is at -y
    pos = {k: v.copy() for k, v in m.facts.positions.items()}
    pos[subject][:, 1] = pos[landmark][:, 1] - sign * 0.04
    m.facts = dataclasses.replace(m.facts, positions=pos)
    rejected(
        reasons(case, m), "is false by only 0.040 m between centres; a camera needs"
    )  # max(6 cm, the subject's radius)


def test_a_direction_false_by_less_than_the_footprints_is_rejected():
    """Suite 2.0's moka pots: centres past the 6 cm floor, footprints overlapping along the axis."""
    key = ("libero_object", 4)
    case = find(key, "L1", lambda c: c.witness["relations"][0]["relation"] in ("left_of", "right_of"))
    r = case.witness["relations"][0]
    m = model(key)
    subject, landmark = r["subject"]["entities"][0], r["landmarks"][0]["entities"][0]
    sign = -1.0 if r["relation"] == "left_of" else 1.0
    pos = {k: v.copy() for k, v in m.facts.positions.items()}
    centres = max(0.061, m.facts.direction_margin(subject))
    pos[subject][:, 1] = pos[landmark][:, 1] - sign * centres
    entities = dict(m.facts.entities)
    entities[landmark] = dataclasses.replace(entities[landmark], radius=0.09)
    m.facts = dataclasses.replace(m.facts, positions=pos, entities=entities)
    rejected(reasons(case, m), "their footprints are")


def test_a_misstated_or_missing_margin_is_rejected():
    case = find(("libero_object", 4), "L1", lambda c: "margin_m" in c.witness["relations"][0])
    rejected(reasons(with_relation(case, margin_m=case.witness["relations"][0]["margin_m"] + 0.05)), "does not match")
    rel = {k: v for k, v in case.witness["relations"][0].items() if k != "margin_m"}
    rejected(reasons(dataclasses.replace(case, witness={**case.witness, "relations": [rel]})), "needs its margin_m")


def test_left_or_right_in_a_left_right_relation_reads_as_a_contradiction():
    def right_plate(r):
        return r["subject"]["phrase"] == "right plate" and len(r["landmarks"]) == 1

    case = find(("libero_10", 4), "L3", lambda c: any(right_plate(r) for r in c.witness["relations"]))
    index = next(i for i, r in enumerate(case.witness["relations"]) if right_plate(r))
    rejected(reasons(with_relation(case, index, relation="left_of")), "'right' reads as a contradiction")


def test_on_with_an_absurd_holder_is_rejected():
    key = ("libero_object", 4)
    case = find(key, "L1", lambda c: c.witness["relations"][0]["subject"]["phrase"] == "ketchup")
    text = "the ketchup on the milk"
    planted = with_relation(
        dataclasses.replace(case, instruction=case.instruction.replace(case.witness["relations"][0]["text"], text)),
        text=text,
        relation="on",
        landmarks=[{"phrase": "milk", "entities": ["milk_1"]}],
    )
    rejected(reasons(planted), "milk_1 is an absurd holder for ketchup_1")


def test_a_claim_made_twice_is_rejected():
    case = find(("libero_object", 4), "L2", lambda c: True)
    rels = case.witness["relations"]
    rejected(
        reasons(dataclasses.replace(case, witness={**case.witness, "relations": [rels[0], rels[0]]})), "is made twice"
    )


def test_a_relation_outside_its_step_is_rejected():
    case = find(("libero_object", 4), "L3", lambda c: c.witness["relations"][0]["step"] == 2)
    rejected(reasons(with_relation(case, step=1)), "is not in step 1")


def test_too_few_paired_states_are_rejected():
    case = find(("libero_object", 4), "L1", lambda c: True)
    rejected(reasons(dataclasses.replace(case, init_states=tuple(range(10)))), "a claim needs at least 25")


def test_the_geometry_behind_the_margin_rule():
    facts = load_scene_facts()[("libero_object", 4)]
    a, b = "ketchup_1", "milk_1"
    clear = facts.clearance("left_of", a, b)
    assert np.allclose(clear, facts.positions[a][:, 1] - facts.positions[b][:, 1])
    false = facts.false_states("left_of", a, b)
    assert all(clear[s] >= facts.direction_margin(a) for s in false)


# -- round 1 review: twin bowls, a camera margin with headroom, things riding on a moved thing ------------
def _twin_relation(c):
    return next((r for r in c.witness["relations"] if r["subject"]["entities"] == ["akita_black_bowl_1"]), None)


def test_no_generated_relation_is_about_a_twinned_bowl():
    """Readers attached "the black bowl next to the ramekin that is behind the stove" to the ramekin as
    often as to the bowl, so a twin gets no spatial claim (its plate or an added step carries it)."""
    seen = 0
    for level in LEVELS:
        for case in cases(("libero_spatial", 1), level, limit=40):
            for r in case.witness["relations"]:
                assert _twin_relation(case) is None and "akita_black_bowl_2" not in r["subject"]["entities"]
                seen += 1
    assert seen >= 20


def _planted_twin(key, relation="behind"):
    """A libero_spatial L1 case whose relation is moved onto the scored (twinned) bowl."""
    case = find(key, "L1", lambda c: len(c.witness["relations"][0]["landmarks"]) == 1)
    r = dict(case.witness["relations"][0])
    r.update(relation=relation, subject={"phrase": "black bowl", "entities": ["akita_black_bowl_1"]})
    return dataclasses.replace(case, witness={**case.witness, "relations": [r]})


def test_a_relation_about_a_twinned_bowl_is_rejected():
    planted = _planted_twin(("libero_spatial", 1))
    rejected(reasons(planted), "a relation about a twinned object")
    # the unnamed twin too ("the black bowl" meant as the OTHER bowl)
    other = with_relation(planted, subject={"phrase": "black bowl", "entities": ["akita_black_bowl_2"]})
    rejected(reasons(other), "a relation about a twinned object")


def test_an_in_relation_about_a_drawers_contents_is_rejected():
    case = find(("libero_goal", 8), "L1", lambda c: True)
    r = dict(case.witness["relations"][0])
    r.update(
        relation="in", landmarks=[{"phrase": "top drawer of the cabinet", "entities": ["wooden_cabinet_1_top_region"]}]
    )
    planted = dataclasses.replace(case, witness={**case.witness, "relations": [r]})
    rejected(reasons(planted), "the camera cannot see inside a closed drawer")
    for level in LEVELS:  # and the generator never writes one
        for c in cases(("libero_goal", 8), level, limit=40):
            for rel in c.witness["relations"]:
                assert not (rel["relation"] == "in" and "drawer" in rel["landmarks"][0]["phrase"]), c.instruction


def test_a_relation_about_what_rests_on_a_thing_an_earlier_step_moves_is_rejected():
    # libero_spatial 3: the scored bowl sits on the cookie box; sliding the box aside moves the bowl too
    planted = _planted_twin(("libero_spatial", 3))
    r = dict(planted.witness["relations"][0], step=2)
    steps = ["slide the cookie box to one side", planted.witness["steps"][0]]
    planted = dataclasses.replace(
        planted,
        instruction=f"{steps[0]}, then {planted.instruction}",
        witness={
            **planted.witness,
            "steps": steps,
            "relations": [r],
            "step_roles": ["added", "original"],
            "step_goals": [[], planted.witness["step_goals"][0]],
            "step_entities": [["cookies_1"], planted.witness["step_entities"][0]],
        },
    )
    rejected(reasons(planted), "akita_black_bowl_1, which an earlier step moves or operates (akita_black_bowl_1)")


def test_a_direction_false_by_five_centimetres_is_now_too_close_to_see():
    key = ("libero_object", 4)
    m = model(key)

    def small_direction(c):  # a subject narrower than 6 cm, so the 6 cm floor is what applies
        r = c.witness["relations"][0]
        return r["relation"] in DIRECTIONS and m.facts.direction_margin(r["subject"]["entities"][0]) == 0.06

    case = find(key, "L3", small_direction)
    r = case.witness["relations"][0]
    subject, landmark = r["subject"]["entities"][0], r["landmarks"][0]["entities"][0]
    axis, sign = DIRECTIONS[r["relation"]]
    pos = {k: v.copy() for k, v in m.facts.positions.items()}
    pos[subject][:, axis] = pos[landmark][:, axis] - sign * 0.054  # the 5.0-5.4 cm readers called borderline
    m.facts = dataclasses.replace(m.facts, positions=pos)
    rejected(reasons(case, m), "is false by only 0.054 m between centres; a camera needs 0.060 m")


# -- round 1b review: a bare relation reads as a destination; a twin's bare noun is no landmark ----------
def test_every_relation_is_a_relative_clause_or_participle_after_its_subject():
    seen = 0
    for key in TASKS:
        for level in LEVELS:
            for case in cases(key, level, limit=10):
                for r in case.witness["relations"]:
                    rest = r["text"].removeprefix("the " + r["subject"]["phrase"])
                    assert rest.startswith((" that is ", " which is ", " sitting ", " resting ")), r["text"]
                    seen += 1
    assert seen >= 40


def test_a_bare_relation_after_a_moved_object_is_rejected():
    # "take the butter to the left of the milk and put it in the basket": the relation reads as where to put it
    case = find(("libero_object", 4), "L1", lambda c: c.witness["relations"][0]["text"].split()[-1] != "basket")
    r = case.witness["relations"][0]
    bare_text = r["text"].replace(" that is ", " ", 1).replace(" which is ", " ", 1)
    assert bare_text != r["text"]
    planted = dataclasses.replace(
        case,
        instruction=case.instruction.replace(r["text"], bare_text),
        witness={**case.witness, "steps": [s.replace(r["text"], bare_text) for s in case.witness["steps"]]},
    )
    rejected(reasons(with_relation(planted, text=bare_text)), "is not a relative clause or participle")
    assert not any("relative clause" in x for x in reasons(case))


def test_no_landmark_is_a_twin_and_a_landmark_meaning_both_bowls_is_rejected():
    key = ("libero_spatial", 1)
    found = None
    for level in LEVELS:
        for case in cases(key, level, limit=40):
            for r in case.witness["relations"]:
                for lm in r["landmarks"]:
                    assert not {"akita_black_bowl_1", "akita_black_bowl_2"} & set(lm["entities"]), case.instruction
                if r["relation"] in DIRECTIONS and r["subject"]["entities"] == ["glazed_rim_porcelain_ramekin_1"]:
                    found = found or case
    case = found or find(key, "L3", lambda c: c.witness["relations"][0]["relation"] in DIRECTIONS)
    # "move the ramekin that is left of the black bowl out of the way": which black bowl?
    planted = with_relation(
        case, landmarks=[{"phrase": "black bowl", "entities": ["akita_black_bowl_1", "akita_black_bowl_2"]}]
    )
    rejected(reasons(planted), "landmark 'black bowl' could mean any of akita_black_bowl_1, akita_black_bowl_2")


def test_no_direction_against_a_fixture_that_faces_its_own_way():
    """ "in front of the wooden cabinet": the drawers' side or the camera's? Readers split, so no
    direction is claimed against a fixture with drawers or a door, and the validator rejects one."""
    for level in LEVELS:
        for c in cases(("libero_goal", 8), level, limit=40):
            for r in c.witness["relations"]:
                if r["relation"] in DIRECTIONS:
                    assert "cabinet" not in r["landmarks"][0]["phrase"], c.instruction
    case = find(("libero_goal", 8), "L1", lambda c: c.witness["relations"][0]["relation"] in DIRECTIONS)
    r = dict(case.witness["relations"][0])
    r.update(landmarks=[{"phrase": "wooden cabinet", "entities": ["wooden_cabinet_1"]}])
    planted = dataclasses.replace(case, witness={**case.witness, "relations": [r]})
    rejected(reasons(planted), "a fixture that faces its own way")


def test_no_next_to_between_two_things_of_one_kind():
    """ "the right plate which is beside the left plate": two plates read as side by side at any gap."""
    key = ("libero_10", 4)
    for level in LEVELS:
        for c in cases(key, level, limit=40):
            for r in c.witness["relations"]:
                if r["relation"] == "next_to":
                    assert not ("plate" in r["subject"]["phrase"] and "plate" in r["landmarks"][0]["phrase"])
    case = find(key, "L3", lambda c: True)
    r = dict(case.witness["relations"][0])
    r.update(
        relation="next_to",
        subject={"phrase": "right plate", "entities": ["plate_2"]},
        landmarks=[{"phrase": "left plate", "entities": ["plate_1"]}],
    )
    rejected(reasons(dataclasses.replace(case, witness={**case.witness, "relations": [r]})), "two things of one kind")
