"""The affordance table and the absent-referent lexicon: coverage, the judgements operators rely
on, and clear errors for a malformed table."""

from __future__ import annotations

import json

import pytest

from conflictbench.tasks.libero.base_tasks import all_base_tasks, base_task
from conflictbench.tasks.scene.affordances import (
    AFFORDANCES,
    AffordanceTableError,
    category,
    fits_inside,
    load_table,
    parse_table,
    table_path,
)
from conflictbench.tasks.scene.facts import load_scene_facts
from conflictbench.tasks.scene.lexicon import absence_problem, absent_concepts, absent_for, scene_vocabulary


@pytest.mark.sim  # LIBERO's base tasks
def test_every_category_of_the_40_base_tasks_is_in_the_table():
    table = load_table()
    used = {c for t in all_base_tasks() for c in [*t.problem.objects.values(), *t.problem.fixtures.values()]}
    assert used - set(table) == set()
    assert len(used) >= 30


@pytest.mark.parametrize("cat", ["flat_stove", "wooden_cabinet", "white_cabinet", "wine_rack", "microwave", "table"])
def test_fixtures_cannot_be_carried_and_are_fixed(cat):
    assert category(cat).lacks("graspable") and category(cat).has("fixed") is True


@pytest.mark.parametrize(
    "cat,affordance,value",
    [
        ("plate", "container", False),
        ("plate", "support", True),
        ("akita_black_bowl", "container", True),
        ("basket", "container", True),
        ("wine_bottle", "support", False),
        ("ketchup", "container", False),
        ("flat_stove", "turnable", True),
        ("flat_stove", "openable", False),
        ("microwave", "openable", True),
        ("porcelain_mug", "turnable", False),
        ("butter", "pourable", False),
        ("milk", "pourable", True),
        ("black_book", "openable", True),
        ("desk_caddy", "graspable", None),
        ("moka_pot", "openable", None),
        ("moka_pot", "turnable", None),  # electric moka pots exist
        ("moka_pot", "container", None),  # its chambers unscrew
    ],
)
def test_judgements_the_operators_rely_on(cat, affordance, value):
    assert category(cat).has(affordance) is value


def test_null_is_never_a_violation():
    caddy = category("desk_caddy")
    assert caddy.has("graspable") is None and not caddy.lacks("graspable")


def test_fits_inside_needs_a_container_and_room():
    assert fits_inside("akita_black_bowl", "glazed_rim_porcelain_ramekin") is False  # larger class
    assert fits_inside("ketchup", "plate") is False  # not a container
    assert fits_inside("ketchup", "basket") is True
    assert fits_inside("ketchup", "wine_rack") is None  # unclear: never used as a violation


def test_size_classes_agree_with_the_simulated_geometry():
    """A hand-sized object is never wider than a large one, as measured in the scenes."""
    radius: dict[str, list[float]] = {}
    for facts in load_scene_facts().values():
        for e in facts.entities.values():
            if e.kind == "object" and e.radius:
                radius.setdefault(e.category, []).append(e.radius)
    small = [max(r) for c, r in radius.items() if category(c).size == 1]
    large = [min(r) for c, r in radius.items() if category(c).size == 3]
    assert small and large and max(small) < min(large)


def test_every_row_documents_itself():
    for info in load_table().values():
        assert info.note and info.names and set(info.affordances) == set(AFFORDANCES)


def _row(**override) -> str:
    row = {
        "category": "thing",
        "names": ["thing"],
        "synonyms": [],
        "hypernyms": [],
        "size": 1,
        "note": "n",
        **{a: False for a in AFFORDANCES},
    }
    row.update(override)
    return json.dumps(row)


@pytest.mark.parametrize(
    "line,field",
    [
        (_row(graspable="yes"), "graspable"),
        (_row(size=7), "size"),
        (_row(names=[]), "names"),
        (_row(names=["Thing"]), "names"),
        ('{"category": "x"}', "names"),
    ],
)
def test_a_malformed_table_names_line_and_field(line, field):
    with pytest.raises(AffordanceTableError, match=rf"t.jsonl line 2, field '{field}'"):
        parse_table(_row() + "\n" + line, "t.jsonl")


def test_the_shipped_table_parses_from_its_file():
    assert parse_table(table_path().read_text(), "x") == load_table()


# -- absent referents ------------------------------------------------------------------------------
@pytest.mark.sim  # LIBERO's base tasks
def test_absence_refuses_names_synonyms_categories_and_shared_words():
    problem = base_task("libero_10", 4).problem  # mugs and plates
    assert absence_problem("cup", (), problem)  # a synonym of mug
    assert absence_problem("blue mug", (), problem)  # a kind of mug
    assert absence_problem("dishware", (), problem)  # a category of the plate
    assert absence_problem("red apple", (), problem)  # shares "red" with the red mug
    assert absence_problem("banana", (), problem) is None
    problem = base_task("libero_object", 2).problem  # has ketchup, milk, basket
    assert absence_problem("laundry hamper", (), problem)  # a hamper is a basket
    assert absence_problem("teapot", ("pot",), base_task("libero_10", 2).problem)  # moka pot present


@pytest.mark.sim  # LIBERO's base tasks
def test_every_absent_referent_is_absent_somewhere_and_roles_are_filled_everywhere():
    for concept in absent_concepts():
        assert any(absence_problem(concept.phrase, concept.synonyms, t.problem) is None for t in all_base_tasks())
    for task in all_base_tasks():
        for role in ("object", "support", "container", "appliance", "openable"):
            assert len(absent_for(task.problem, role)) >= 3, (task.key, role)


@pytest.mark.sim  # LIBERO's base tasks
def test_scene_vocabulary_includes_region_words_and_the_robot():
    phrases, _ = scene_vocabulary(base_task("libero_goal", 0).problem)
    assert {"drawer", "top drawer", "gripper", "stove", "cooktop"} <= phrases
