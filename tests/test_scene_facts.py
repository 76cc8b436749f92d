"""Scene facts: the geometry of relations, the shipped file, and a re-derivation from the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from conflictbench.tasks.libero.base_tasks import all_base_tasks, load_init_states
from conflictbench.tasks.scene import facts as scene
from conflictbench.tasks.scene.facts import (
    DIRECTION_MARGIN,
    FAR_GAP,
    Entity,
    SceneFactsError,
    TaskFacts,
    file_sha256,
    format_scene_facts,
    load_scene_facts,
    parse_scene_facts,
    shipped_facts_path,
    states_sha256,
)


def _facts(positions: dict[str, list], radius=0.05, contacts=None, predicates=None) -> TaskFacts:
    n = len(next(iter(positions.values())))
    entities = {k: Entity(k, "thing", "object", radius=radius) for k in positions}
    return TaskFacts(
        "libero_goal",
        0,
        "",
        "",
        n,
        entities,
        {k: np.asarray(v, float) for k, v in positions.items()},
        contacts or {},
        predicates or {},
        frozenset(range(n)),
    )


def test_directions_follow_the_camera_view_with_a_margin():
    # state 0: a clearly at -y of b (left); 1: a 1 cm to the right (too close to call); 2: clearly right
    f = _facts({"a": [[0, -0.2, 0], [0, 0.01, 0], [0, 0.2, 0]], "b": [[0, 0, 0]] * 3})
    assert f.holds("left_of", "a", "b") == {0, 1}
    assert f.holds("right_of", "a", "b") == {1, 2}
    assert f.false_states("left_of", "a", "b") == {2}
    assert f.holds("in_front_of", "a", "b") == {0, 1, 2}  # same x: neither clearly in front nor behind
    f = _facts({"a": [[0.12, 0, 0]], "b": [[0, 0, 0]]})
    assert f.holds("behind", "a", "b") == set() and f.holds("in_front_of", "a", "b") == {0}


def test_next_to_uses_footprint_gaps():
    near = 0.05 + 0.05 + FAR_GAP - 0.01
    f = _facts({"a": [[0, 0, 0], [0, 0, 0]], "b": [[near, 0, 0], [near + 0.05, 0, 0]]})
    assert f.holds("next_to", "a", "b") == {0}


def test_between_is_lenient_about_overshoot_but_not_about_the_side():
    f = _facts({"a": [[0.5, 0, 0], [1.1, 0, 0], [0.5, 0.4, 0]], "b": [[0, 0, 0]] * 3, "c": [[1, 0, 0]] * 3}, radius=0.0)
    assert f.holds("between", "a", "b", "c") == {0, 1}


def test_between_is_false_only_clearly_beyond_an_end():
    # a short b-c segment (20 cm): 15 % is 3 cm, so the footprints decide: radii 3 cm, so a must lie
    # 3 + 3 + 1 cm past c's centre; 5 cm past still counts as between, 8 cm does not
    f = _facts({"a": [[0.25, 0, 0], [0.28, 0, 0]], "b": [[0, 0, 0]] * 2, "c": [[0.2, 0, 0]] * 2}, radius=0.03)
    assert f.holds("between", "a", "b", "c") == {0}


def test_on_and_in_count_any_contact_as_true():
    touch = {frozenset(("a", "b")): frozenset({1})}
    f = _facts(
        {"a": [[0, 0, 0.1]] * 3, "b": [[0, 0, 0]] * 3}, contacts=touch, predicates={("on", "a", "b"): frozenset({2})}
    )
    assert f.holds("on", "a", "b") == {1, 2}
    assert f.false_states("on", "a", "b") == {0}


def test_unknown_relation_or_entity_is_an_error():
    f = _facts({"a": [[0, 0, 0]], "b": [[0, 0, 0]]})
    with pytest.raises(SceneFactsError, match="unknown spatial relation"):
        f.holds("under", "a", "b")
    with pytest.raises(SceneFactsError, match="no entity 'c'"):
        f.holds("on", "a", "c")


def test_directional_margin_is_stated_in_code():
    assert DIRECTION_MARGIN == pytest.approx(0.06)  # 5 cm, the minimum, and a centimetre of headroom


def test_a_direction_is_false_only_with_the_footprints_a_centimetre_apart_along_its_axis():
    # a lies 4, 6 and 9 cm to the RIGHT of b's centre, both of radius 3 cm: "a left of b" is false
    # only where the footprints are apart (9 - 3 - 3 = 3 cm), not at 6 cm (they touch) ...
    f = _facts({"a": [[0, 0.04, 0], [0, 0.06, 0], [0, 0.09, 0]], "b": [[0, 0, 0]] * 3}, radius=0.03)
    assert f.false_states("left_of", "a", "b") == {2}
    assert np.allclose(f.clearance("left_of", "a", "b"), [0.04, 0.06, 0.09])
    assert np.allclose(f.footprint_gap("left_of", "a", "b"), [-0.02, 0.0, 0.03])
    # ... and things of radius 8 cm need 17 cm between centres
    f = _facts({"a": [[0, 0.09, 0], [0, 0.16, 0], [0, 0.17, 0]], "b": [[0, 0, 0]] * 3}, radius=0.08)
    assert f.false_states("left_of", "a", "b") == {2}


def test_the_moka_pots_readers_flagged_are_not_in_front_of_each_other_by_a_margin():
    """Suite 2.0: "the right moka pot in front of the left moka pot", the right pot 63-95 mm BEHIND
    the left one and a pot's radius 91 mm: centres far enough apart, footprints overlapping."""
    f = _facts({"right": [[-0.063, 0.1, 0], [-0.095, 0.1, 0]], "left": [[0, -0.1, 0]] * 2}, radius=0.091)
    assert f.holds("in_front_of", "right", "left") == {0, 1}
    assert (f.clearance("in_front_of", "right", "left") >= 0.06).all()


# -- the shipped file -------------------------------------------------------------------------------
@pytest.mark.sim  # LIBERO's base tasks
def test_shipped_facts_cover_every_base_task_with_50_states():
    facts = load_scene_facts()
    assert set(facts) == {t.key for t in all_base_tasks()}
    for task in all_base_tasks():
        f = facts[task.key]
        assert f.n_states == 50
        assert f.bddl_sha256 == file_sha256(task.bddl_path)
        assert f.init_states_sha256 == states_sha256(load_init_states(*task.key))
        assert set(task.problem.objects) <= set(f.entities)


def test_facts_agree_with_the_bddl_init_for_fixed_support():
    """libero_10 task 3: the bottom drawer starts open and the bowl on the table, in every state."""
    f = load_scene_facts()[("libero_10", 3)]
    assert f.predicate("open", "white_cabinet_1_bottom_region") == f.states()
    assert f.false_states("in", "akita_black_bowl_1", "white_cabinet_1_bottom_region") == f.states()


def test_round_trip_and_tampering(tmp_path):
    facts = load_scene_facts()
    text = format_scene_facts(list(facts.values())[:2], {"libero": "x"})
    parsed = parse_scene_facts(text, "f.jsonl")
    key = next(iter(parsed))
    name = next(iter(facts[key].positions))
    assert np.allclose(parsed[key].positions[name], facts[key].positions[name], atol=5e-4)
    assert parsed[key].predicates == facts[key].predicates
    lines = text.splitlines()
    tampered = "\n".join([lines[0], lines[1].replace('"states":50', '"states":49'), *lines[2:]])
    with pytest.raises(SceneFactsError, match="f.jsonl line 1, field 'sha256'"):
        parse_scene_facts(tampered, "f.jsonl")
    with pytest.raises(SceneFactsError, match="line 1: missing the 'conflictbench-scene-facts' header"):
        parse_scene_facts("\n".join(lines[1:]), "f.jsonl")
    broken = lines[1].replace('"entities"', '"entitiez"')
    fixed_header = text.splitlines()[0].replace(scene._checksum(lines[1:]), scene._checksum([broken, *lines[2:]]))
    with pytest.raises(SceneFactsError, match="f.jsonl line 2: malformed scene facts"):
        parse_scene_facts("\n".join([fixed_header, broken, *lines[2:]]), "f.jsonl")


def test_missing_facts_file_says_how_to_build_it(tmp_path):
    with pytest.raises(SceneFactsError, match="suite build --facts"):
        load_scene_facts(tmp_path / "none.jsonl")


# -- against the real simulator ---------------------------------------------------------------------
SAMPLE = [(("libero_spatial", 4), (0, 17, 49)), (("libero_10", 6), (3, 30))]


@pytest.mark.e2e
@pytest.mark.sim
@pytest.mark.parametrize("key,states", SAMPLE, ids=[f"{k[0]}-{k[1]}" for k, _ in SAMPLE])
def test_a_sample_of_shipped_facts_matches_a_fresh_simulator(key, states):
    from conflictbench.sim.scene_facts import derive_in_subprocess

    fresh = derive_in_subprocess(*key, states=states)
    shipped = load_scene_facts()[key]
    assert fresh.bddl_sha256 == shipped.bddl_sha256 and fresh.init_states_sha256 == shipped.init_states_sha256
    assert set(fresh.entities) == set(shipped.entities)
    for row, state in enumerate(states):
        for name in fresh.entities:
            assert np.allclose(fresh.positions[name][row], shipped.positions[name][state], atol=1e-3), (name, state)
    chosen = frozenset(states)
    assert {k: v & chosen for k, v in fresh.contacts.items() if v} == {
        k: v & chosen for k, v in shipped.contacts.items() if v & chosen
    }
    assert {k: v for k, v in fresh.predicates.items() if v} == {
        k: v & chosen for k, v in shipped.predicates.items() if v & chosen
    }
    for name, entity in fresh.entities.items():
        if entity.radius is not None:
            assert entity.radius == pytest.approx(shipped.entities[name].radius, abs=1e-3)


def test_shipped_facts_path_is_package_data():
    assert shipped_facts_path().name == "scene_facts.jsonl" and shipped_facts_path().parent.name == "data"
