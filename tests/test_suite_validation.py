"""Validation: the shipped suite passes every rule, and planted invalid cases are rejected, each
for the reason its rule gives."""

from __future__ import annotations

import dataclasses
import time

import pytest
from testing_support import rejected

from conflictbench.core import FAMILIES, LEVELS
from conflictbench.tasks.libero.base_tasks import all_base_tasks
from conflictbench.tasks.scene.facts import load_scene_facts
from conflictbench.tasks.suite.build import SUITE_VERSION
from conflictbench.tasks.suite.file import load_suite
from conflictbench.tasks.validation.rules import Context, new_context, normalise, validate_case, validate_cases

pytestmark = pytest.mark.sim  # nearly every test needs LIBERO's base tasks


@pytest.fixture(scope="module")
def suite():
    return load_suite()


@pytest.fixture(scope="module")
def ctx():
    return new_context()


def pick(suite, family, level=None, key=None, where=lambda c: True):
    return next(
        c
        for c in suite.accepted()
        if c.family == family
        and (level is None or c.level == level)
        and (key is None or (c.suite, c.task_id) == key)
        and where(c)
    )


def with_witness(case, **changes):
    return dataclasses.replace(case, witness={**case.witness, **changes})


# -- the shipped suite --------------------------------------------------------------------------------
def test_the_shipped_suite_validates_completely_and_quickly(suite):
    start = time.perf_counter()
    failures = validate_cases(suite.cases, new_context())
    elapsed = time.perf_counter() - start
    assert failures == []
    assert elapsed < 20  # about a second here: `suite validate` stays fast


def test_volume_and_coverage(suite):
    usable = suite.accepted()
    assert len(usable) >= 1413
    assert {(c.suite, c.task_id) for c in usable} == {t.key for t in all_base_tasks()}
    for family in FAMILIES:
        for level in LEVELS:
            assert sum(1 for c in usable if (c.family, c.level) == (family, level)) >= 50, (family, level)
    keys = [(c.suite, normalise(c.instruction)) for c in suite.cases]  # no text twice within a LIBERO suite
    assert len(keys) == len(set(keys))


def test_case_ids_name_task_family_and_level(suite):
    for c in suite.cases[:200]:
        abbrev, family, level, digest = c.case_id.split("-")
        assert abbrev.endswith(f"{c.task_id:02d}") and family == c.family[:3] and level == c.level and len(digest) == 8


def test_p0_and_p1_come_from_the_one_case(suite, plugins):
    from conflictbench.core import P1_PREAMBLE

    case = suite.accepted()[0]
    assert plugins.format_prompt(case.instruction, "p0", "noop") == case.instruction
    p1 = plugins.format_prompt(case.instruction, "p1", "noop")
    assert P1_PREAMBLE in p1 and p1.endswith(case.instruction)


# -- rules for every family -----------------------------------------------------------------------------
def test_instruction_equal_to_the_base_is_invalid(suite, ctx):
    case = pick(suite, "grounding")
    rejected(
        validate_case(dataclasses.replace(case, instruction=case.base_instruction.upper() + "."), ctx),
        "equals the base instruction",
    )


def test_wrong_base_instruction_or_task(suite, ctx):
    case = pick(suite, "physical")
    rejected(
        validate_case(dataclasses.replace(case, base_instruction="do something"), ctx),
        "is not the task's reference instruction",
    )
    assert validate_case(dataclasses.replace(case, task_id=42), ctx)[0].endswith("not 42")


def test_changed_or_invalid_base_task_is_reported(suite):
    case = pick(suite, "grounding", key=("libero_goal", 8))
    facts = dict(load_scene_facts())
    good = facts[case.suite, case.task_id]
    facts[case.suite, case.task_id] = dataclasses.replace(good, bddl_sha256="0" * 64)
    rejected(validate_case(case, Context(facts)), "BDDL file changed")
    goal = ("on", "akita_black_bowl_1", "plate_1")
    facts[case.suite, case.task_id] = dataclasses.replace(good, predicates={**good.predicates, goal: good.states()})
    rejected(validate_case(case, Context(facts)), "goal already holds")


def test_witness_type_must_fit_the_family(suite, ctx):
    case = pick(suite, "spatial")
    rejected(validate_case(dataclasses.replace(case, family="grounding"), ctx), "does not fit family 'grounding'")


def test_steps_must_be_in_the_text_in_order(suite, ctx):
    case = pick(suite, "grounding", "L3")
    steps = case.witness["steps"]
    rejected(validate_case(with_witness(case, steps=list(reversed(steps))), ctx), "(in order)")
    rejected(validate_case(with_witness(case, steps=["fly to the moon"]), ctx), "is not in the instruction")


def test_level_must_match_the_witness(suite, ctx):
    rejected(
        validate_case(dataclasses.replace(pick(suite, "grounding", "L1"), level="L2"), ctx), "level L2 does not match"
    )
    rejected(
        validate_case(dataclasses.replace(pick(suite, "physical", "L4"), level="L3"), ctx), "level L3 does not match"
    )


def test_duplicate_instruction_within_a_libero_suite(suite, ctx):
    case = pick(suite, "instruction")
    twin = dataclasses.replace(case, case_id="twin", task_id=(case.task_id + 1) % 10)  # another scene, same words
    found = validate_cases([case, twin], ctx, composition=False)
    assert ("twin", f"same instruction as {case.case_id} within {case.suite}") in found


def test_composition_rules_apply_to_a_whole_suite_not_to_a_part(suite, ctx):
    """An export of three physical cases cannot show four kinds per level: only a whole suite must."""
    part = [c for c in suite.accepted() if c.family == "physical" and c.level == "L1"][:3]
    assert validate_cases(part, ctx, composition=False) == []
    assert any("need 4" in reason for _, reason in validate_cases(part, ctx))


def test_init_states_outside_the_fixed_ones(suite, ctx):
    rejected(
        validate_case(dataclasses.replace(pick(suite, "spatial"), init_states=(50, 51)), ctx),
        "are not among the task's 50 states",
    )


# -- grounding ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "replacement,reason",
    [
        ("the plate", "names something in the scene"),
        ("the dish", "names something in the scene"),  # a synonym of the plate and the bowl
        ("the dishware", "names something in the scene"),  # a category of them
        ("the wine glass", "shares the word(s) wine"),
    ],
)
def test_grounding_referent_must_be_truly_absent(suite, ctx, replacement, reason):
    case = pick(suite, "grounding", "L1", key=("libero_goal", 8))
    ref = case.witness["referents"][0]
    planted = dataclasses.replace(
        case,
        instruction=case.instruction.replace(ref["text"], replacement),
        witness={
            **case.witness,
            "steps": [s.replace(ref["text"], replacement) for s in case.witness["steps"]],
            "referents": [{**ref, "text": replacement, "concept": "", "source": "out_of_domain"}],
        },
    )
    rejected(validate_case(planted, ctx), reason)


def test_grounding_referent_must_be_in_the_text(suite, ctx):
    case = pick(suite, "grounding", "L1")
    ref = case.witness["referents"][0]
    rejected(
        validate_case(with_witness(case, referents=[{**ref, "text": "the unicorn"}]), ctx), "is not in the instruction"
    )


# -- spatial --------------------------------------------------------------------------------------------
def _relation_case(suite, relation):
    case = pick(suite, "spatial", "L1", key=("libero_spatial", 0))
    text = "the black bowl between the plate and the ramekin"
    steps = [f"pick up {text} and place it on the plate"]
    return dataclasses.replace(
        case,
        instruction=steps[0],
        init_states=None,
        witness={"type": "false_relation", "steps": steps, "relations": [{**relation, "text": text}]},
    )


def test_a_true_relation_is_rejected(suite, ctx):
    relation = {
        "step": 1,
        "relation": "between",
        "subject": {"phrase": "black bowl", "entities": ["akita_black_bowl_1", "akita_black_bowl_2"]},
        "landmarks": [
            {"phrase": "plate", "entities": ["plate_1"]},
            {"phrase": "ramekin", "entities": ["glazed_rim_porcelain_ramekin_1"]},
        ],
    }
    rejected(validate_case(_relation_case(suite, relation), ctx), "holds in initial state(s)")


def test_a_relation_must_cover_every_entity_its_words_could_mean(suite, ctx):
    relation = {
        "step": 1,
        "relation": "between",
        "subject": {"phrase": "black bowl", "entities": ["akita_black_bowl_2"]},
        "landmarks": [
            {"phrase": "plate", "entities": ["plate_1"]},
            {"phrase": "ramekin", "entities": ["glazed_rim_porcelain_ramekin_1"]},
        ],
    }
    rejected(validate_case(_relation_case(suite, relation), ctx), "could also mean akita_black_bowl_1")


def test_listed_states_must_all_make_the_relation_false(suite, ctx):
    case = pick(suite, "spatial", where=lambda c: c.init_states is not None)
    facts = load_scene_facts()[(case.suite, case.task_id)]
    true_somewhere = sorted(facts.states() - frozenset(case.init_states))
    assert true_somewhere, "a case with listed states leaves some out"
    rejected(
        validate_case(dataclasses.replace(case, init_states=(*case.init_states, true_somewhere[0])), ctx),
        "holds in initial state",
    )


def test_a_relation_must_be_said(suite, ctx):
    case = pick(suite, "spatial", "L1", where=lambda c: c.witness["relations"][0]["relation"] in ("on", "next_to"))
    rel = case.witness["relations"][0]
    other = "behind" if " behind " not in case.instruction else "left_of"
    rejected(validate_case(with_witness(case, relations=[{**rel, "relation": other}]), ctx), "does not say")


# -- physical -------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "violation,reason",
    [
        ({"entity": "plate_1", "needs": "support", "text": "the plate"}, "does not plainly lack 'support'"),
        ({"entity": "basket_1", "needs": "graspable", "text": "the basket"}, "is not in the scene"),
        ({"entity": "flat_stove_1", "needs": "edible", "text": "the stove"}, "unknown affordance"),
        ({"entity": "flat_stove_1", "needs": "graspable", "text": "the cabinet"}, "does not name flat_stove_1"),
    ],
)
def test_physical_violation_must_hold_for_a_present_named_entity(suite, ctx, violation, reason):
    case = pick(
        suite,
        "physical",
        "L1",
        key=("libero_goal", 8),
        where=lambda c: all(v["needs"] != "fits_in" for v in c.witness["violations"]),
    )
    planted = with_witness(case, violations=[{"step": 1, **violation}])
    planted = dataclasses.replace(planted, instruction=planted.instruction + " near " + violation["text"])
    rejected(validate_case(planted, ctx), reason)


def test_unclear_affordances_are_not_violations(suite, ctx):
    case = pick(suite, "physical", "L1", key=("libero_10", 5))
    planted = with_witness(
        case, violations=[{"step": 1, "entity": "desk_caddy_1", "needs": "graspable", "text": "the caddy"}]
    )
    rejected(validate_case(planted, ctx), "does not plainly lack 'graspable'")


# -- instruction ----------------------------------------------------------------------------------------
def test_compatible_requirements_are_not_a_contradiction(suite, ctx):
    case = pick(suite, "instruction", "L1", key=("libero_goal", 8))
    goal = next(r for r in case.witness["requirements"] if r["literal"][0] == "goal")
    harmless = {"id": "r9", "step": 1, "text": "the cream cheese", "literal": ["keep", "untouched", "cream_cheese_1"]}
    planted = dataclasses.replace(
        case,
        instruction=case.instruction + ", and leave the cream cheese alone",
        witness={**case.witness, "requirements": [goal, harmless], "conflicts": [[goal["id"], "r9"]]},
    )
    rejected(validate_case(planted, ctx), "do not contradict")


def test_requirement_text_must_be_in_the_instruction(suite, ctx):
    case = pick(suite, "instruction", "L1")
    reqs = [dict(r) for r in case.witness["requirements"]]
    reqs[-1]["text"] = "while singing"
    rejected(validate_case(with_witness(case, requirements=reqs), ctx), "is not in the instruction")


def test_the_interim_witness_shapes_are_findings_not_crashes(suite, ctx):
    case = pick(suite, "grounding", "L1")
    planted = with_witness(case, referents=["banana"])
    assert any(r.startswith("malformed witness") for r in validate_case(planted, ctx))
    rejected(
        validate_case(dataclasses.replace(case, witness={"type": "absent_referent", "referents": []}), ctx),
        "witness field 'steps' must list",
    )


def test_no_old_case_id_is_reused_for_new_text(suite):
    """Suite 1.1.0's ids (kept as id + a hash of the text): an id the new suite shares names the same text."""
    import hashlib
    from pathlib import Path

    old = {}
    for line in (Path(__file__).parent / "data" / "suite-1.1.0-ids.tsv").read_text().splitlines():
        if not line.startswith("#"):
            case_id, digest = line.split("\t")
            old[case_id] = digest
    assert len(old) == 1869  # 1,868 usable and one removed in review
    shared = [c for c in suite.cases if c.case_id in old]
    for c in shared:
        assert hashlib.sha256(c.instruction.encode()).hexdigest()[:16] == old[c.case_id], c.case_id
    assert suite.version == SUITE_VERSION == "2.1.0"
