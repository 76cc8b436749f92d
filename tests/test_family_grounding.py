"""The grounding family: referents from three sources, only object / destination / receptacle roles,
a checked synonym table, wrong attributes, and L2's two different roles. Each validator rule is shown
rejecting a planted case; generated cases pass."""

from __future__ import annotations

import dataclasses
import random
from collections import Counter

import pytest
from testing_support import rejected

from conflictbench.core import LEVELS
from conflictbench.tasks.scene.affordances import load_table
from conflictbench.tasks.scene.lexicon import (
    COLOURS,
    NEAR_COLOURS,
    close_colours,
    colourings,
    denotations,
    near_synonyms,
)

# -- the tables (no simulator needed) ----------------------------------------------------------------
KNOWN_NEAR_SYNONYMS = {
    "basket": {"bucket", "pail", "bin", "crate", "hamper", "colander", "tub"},
    "porcelain_mug": {"cup", "beaker"},
    "wooden_cabinet": {"drawer", "cupboard", "dresser", "chest"},
    "flat_stove": {"cooktop", "burner", "hob", "range"},
}


def test_the_synonym_table_covers_every_category():
    assert set(near_synonyms()) == set(load_table())
    for cat in load_table():
        assert near_synonyms()[cat], cat


@pytest.mark.parametrize("cat,words", sorted(KNOWN_NEAR_SYNONYMS.items()))
def test_the_known_near_synonyms_denote_their_category(cat, words):
    assert words <= denotations(cat)


def test_attributes_are_known_colours_of_table_categories():
    for cat, colouring in colourings().items():
        assert cat in load_table()
        assert set(colouring.colours) <= set(COLOURS) | set(NEAR_COLOURS)  # each has its close colours


def test_wood_is_recorded_as_wood_and_its_tones_are_close_to_it():
    assert colourings()["wooden_cabinet"].colours == ("wood",)
    assert {"yellow", "orange", "tan", "beige", "brown", "gold"} <= close_colours("wood")
    # only colours far from black, white and wood are left for a wrong attribute against them
    taken = close_colours("black") | close_colours("white") | close_colours("wood")
    assert [c for c in COLOURS if c not in taken] == ["red", "blue", "green", "purple", "pink"]


def test_closeness_reads_both_ways():
    for colour in NEAR_COLOURS:
        for near in close_colours(colour):
            assert colour in close_colours(near), (colour, near)


# -- generated and planted cases -------------------------------------------------------------------
@pytest.fixture(scope="module")
def ctx():
    from conflictbench.tasks.validation.rules import new_context

    return new_context()


def _model(key):
    from conflictbench.tasks.libero.base_tasks import base_task
    from conflictbench.tasks.scene.facts import load_scene_facts
    from conflictbench.tasks.scene.task_model import build_model

    return build_model(base_task(*key), load_scene_facts()[key])


def _cases(key, level, limit=60):
    from conflictbench.tasks.operators.grounding import generate
    from conflictbench.tasks.suite.build import _to_case

    m = _model(key)
    out = []
    for d in generate(m, level, random.Random(0)):
        out.append(_to_case(m.task, d))
        if len(out) >= limit:
            break
    return out


def _valid(case, ctx):
    from conflictbench.tasks.validation.rules import validate_case

    return validate_case(case, ctx)


def _case(key, level, ctx, where):
    return next(c for c in _cases(key, level) if where(c) and not _valid(c, ctx))


def _swap(case, old, new, **ref_changes):
    """The case with one referent's text replaced everywhere (and its witness fields changed)."""
    refs = [dict(r) for r in case.witness["referents"]]
    i = next(i for i, r in enumerate(refs) if r["text"] == old)
    refs[i].update(text=new, **ref_changes)
    witness = {**case.witness, "steps": [s.replace(old, new) for s in case.witness["steps"]], "referents": refs}
    return dataclasses.replace(case, instruction=case.instruction.replace(old, new), witness=witness)


def _role(case, role):
    return next(r for r in case.witness["referents"] if r["role"] == role)


BASKET_TASK = ("libero_object", 0)  # alphabet soup into the basket
BOWL_TASK = ("libero_spatial", 0)  # black bowls, a white ramekin, a plate, a cabinet, a stove


@pytest.mark.sim
@pytest.mark.parametrize("level", LEVELS)
def test_generated_cases_validate_at_every_level(level, ctx):
    for key in [BASKET_TASK, BOWL_TASK, ("libero_goal", 7), ("libero_10", 3), ("libero_10", 4)]:
        for case in _cases(key, level, limit=15):
            assert _valid(case, ctx) == [], (case.instruction, _valid(case, ctx))
            for r in case.witness["referents"]:
                assert r["role"] in ("object", "destination", "receptacle")
                assert r["text"] in case.witness["steps"][r["step"] - 1]


@pytest.mark.sim
def test_all_three_sources_appear_and_l2_replaces_object_and_destination():
    seen = Counter()
    for key in [BOWL_TASK, ("libero_goal", 8)]:
        for case in _cases(key, "L2", limit=60):
            roles = sorted(r["role"] for r in case.witness["referents"])
            assert roles in (["destination", "object"], ["object", "receptacle"])
            seen.update(r["source"] for r in case.witness["referents"])
    assert set(seen) == {"libero", "attribute", "out_of_domain"}


@pytest.mark.sim
@pytest.mark.parametrize(
    "near",
    ["the bucket", "the pail", "the colander", "the crate", "the laundry hamper", "the plastic bin", "the tub"],
)
def test_a_near_synonym_of_the_basket_is_not_absent(near, ctx):
    case = _case(BASKET_TASK, "L1", ctx, lambda c: _role(c, "receptacle") if c.factors == ("receptacle",) else None)
    ref = _role(case, "receptacle")
    rejected(_valid(_swap(case, ref["text"], near, source="out_of_domain", concept=""), ctx), "not absent")


@pytest.mark.sim
@pytest.mark.parametrize("near", ["the cupboard", "the chest of drawers", "the dresser", "the hob", "the cooktop"])
def test_near_synonyms_of_cabinet_and_stove_are_not_absent(near, ctx):
    case = _case(BOWL_TASK, "L1", ctx, lambda c: c.factors == ("destination",))
    ref = _role(case, "destination")
    rejected(_valid(_swap(case, ref["text"], near, source="out_of_domain", concept=""), ctx), "not absent")


@pytest.mark.sim
def test_a_landmark_is_never_a_referent(ctx):
    case = _case(BOWL_TASK, "L1", ctx, lambda c: c.factors == ("destination",))
    ref = _role(case, "destination")
    rejected(_valid(_swap(case, ref["text"], ref["text"], role="landmark"), ctx), "a missing landmark alone")


@pytest.mark.sim
def test_the_witness_names_source_and_replaced_entity(ctx):
    case = _case(BOWL_TASK, "L1", ctx, lambda c: c.factors == ("destination",))
    text = _role(case, "destination")["text"]
    rejected(_valid(_swap(case, text, text, source="made_up"), ctx), "has source 'made_up'")
    rejected(_valid(_swap(case, text, text, replaces=None), ctx), "does not say which scene entity")
    rejected(_valid(_swap(case, text, text, replaces="akita_black_bowl_1"), ctx), "is not the destination of step 1")


@pytest.mark.sim
@pytest.mark.parametrize(
    "phrase,reason",
    [
        ("the black bowl", "may denote something in the scene"),  # its real colour
        ("the white bowl", "may denote something in the scene"),  # the ramekin is a white bowl
        ("the grey bowl", "is not a colour of the attribute table"),  # too close to black
        ("the red teapot", "nothing in the scene is a 'teapot'"),  # not an attribute of anything present
    ],
)
def test_a_wrong_attribute_must_be_clearly_wrong(phrase, reason, ctx):
    case = _case(
        BOWL_TASK, "L1", ctx, lambda c: c.factors == ("object",) and _role(c, "object")["source"] == "attribute"
    )
    ref = _role(case, "object")
    rejected(_valid(_swap(case, ref["text"], phrase), ctx), reason)


CABINET_TASK = ("libero_goal", 0)  # open the middle drawer of the (wooden) cabinet


@pytest.mark.sim
@pytest.mark.parametrize("colour", ["yellow", "orange"])
def test_a_wood_tone_is_not_a_wrong_colour_for_a_wooden_cabinet(colour, ctx):
    case = _case(
        CABINET_TASK, "L1", ctx, lambda c: _role(c, "object")["source"] == "attribute" and c.factors == ("object",)
    )
    ref = _role(case, "object")
    assert ref["concept"] == "wooden_cabinet" and ref["attribute"] in ("red", "blue", "green", "purple", "pink")
    wrong = ref["text"].replace(ref["attribute"], colour)
    rejected(_valid(_swap(case, ref["text"], wrong, attribute=colour), ctx), "may denote something in the scene")


@pytest.mark.sim
def test_a_libero_referent_must_be_absent_and_share_no_name(ctx):
    case = _case(BOWL_TASK, "L1", ctx, lambda c: c.factors == ("destination",))
    ref = _role(case, "destination")
    rejected(_valid(_swap(case, ref["text"], "the plate", source="libero", concept="plate"), ctx), "not the name of")
    rejected(
        _valid(_swap(case, ref["text"], "the white mug", source="libero", concept="porcelain_mug"), ctx), "not absent"
    )


@pytest.mark.sim
def test_l2_needs_two_different_roles(ctx):
    case = _case(BOWL_TASK, "L2", ctx, lambda c: True)
    refs = [dict(r) for r in case.witness["referents"]]
    for r in refs:
        r["role"] = "object"
        r["replaces"] = "akita_black_bowl_1"
    planted = dataclasses.replace(case, witness={**case.witness, "referents": refs})
    rejected(_valid(planted, ctx), "two different roles of the step")


@pytest.mark.sim
def test_the_referent_is_in_its_own_step(ctx):
    case = _case(BOWL_TASK, "L3", ctx, lambda c: c.witness["referents"][0]["step"] == 2)
    refs = [{**case.witness["referents"][0], "step": 1}]
    rejected(
        _valid(dataclasses.replace(case, witness={**case.witness, "referents": refs}), ctx), "not in the text of step 1"
    )


CADDY_TASK = ("libero_10", 5)  # pick up the book and place it in the back compartment of the caddy


@pytest.mark.sim
@pytest.mark.parametrize("word", ["bucket", "bin", "tub", "crate", "organizer", "container"])
def test_a_receptacle_word_for_the_caddy_is_not_absent(word, ctx):
    case = _case(CADDY_TASK, "L1", ctx, lambda c: c.factors == ("receptacle",))
    ref = _role(case, "receptacle")
    rejected(_valid(_swap(case, ref["text"], f"the {word}", source="out_of_domain", concept=""), ctx), "not absent")


@pytest.mark.sim
def test_generated_receptacles_are_no_word_for_a_present_open_receptacle(ctx):
    from conflictbench.tasks.scene.lexicon import head, receptacle_words

    for key in [CADDY_TASK, BASKET_TASK, ("libero_goal", 6)]:
        taken = receptacle_words(_model(key).problem)
        for level in ("L1", "L3"):
            for case in _cases(key, level, limit=40):
                for r in case.witness["referents"]:
                    if r["role"] == "receptacle" and r["source"] != "attribute":
                        assert head(r["text"]) not in taken, case.instruction


def _pick_half_referent(case):
    steps = case.witness["steps"]
    return (
        len(steps) == 2
        and not case.witness["step_goals"][0]
        and any(r["step"] == 1 and r["role"] == "object" for r in case.witness["referents"])
    )
