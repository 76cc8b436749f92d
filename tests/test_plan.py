"""Planning: references shared between cases, the stratified sample, initial-state restrictions."""

from __future__ import annotations

from collections import Counter

import pytest

from conflictbench.core import FAMILIES, LEVELS, ConflictCase, UserError
from conflictbench.sim.plan import EpisodeSpec, build_plan, episode_id, sample_cases

SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
BASE = {(s, t): f"task {s} {t}" for s in SUITES for t in range(10)}


def case(cid, suite="libero_goal", task=0, family="physical", level="L1", states=None, status="accepted"):
    return ConflictCase(
        cid, suite, task, BASE[(suite, task)], f"conflict {cid}", family, level, init_states=states, status=status
    )


def plan(cases, **kw):
    args = dict(
        base_instructions=BASE, families=FAMILIES, levels=LEVELS, prompts=["p0"], init_states=[0], cases_per_cell=None
    )
    args.update(kw)
    return build_plan(cases, **args)


def test_cases_of_one_base_task_share_one_reference_per_state_and_prompt():
    cases = [case("a"), case("b", level="L2"), case("c", family="spatial")]
    episodes = plan(cases, init_states=[0, 1], prompts=["p0", "p1"])
    refs = [e for e in episodes if e.case is None]
    assert len(refs) == 4  # one base task x 2 states x 2 prompts
    assert len(episodes) - len(refs) == 3 * 2 * 2
    assert Counter(e.reference_key for e in refs).most_common(1)[0][1] == 1
    assert all(e.instruction == BASE[("libero_goal", 0)] for e in refs)


def test_family_level_and_libero_suite_filters():
    cases = [case("a"), case("b", family="spatial"), case("c", level="L3"), case("d", suite="libero_10")]
    got = {e.case_id for e in plan(cases, families=["physical"], levels=["L1"]) if e.case}
    assert got == {"a", "d"}
    got = {e.case_id for e in plan(cases, families=["physical"], levels=["L1"], libero_suites=["libero_10"]) if e.case}
    assert got == {"d"}


def test_only_accepted_and_revised_cases_are_planned():
    cases = [case("a", status="removed"), case("b", status="pending"), case("c", status="revised"), case("d")]
    assert {e.case_id for e in plan(cases) if e.case} == {"c", "d"}


def test_case_initial_states_restrict_pairing():
    episodes = plan([case("a", states=(1, 3))], init_states=[0, 1, 2, 3])
    assert sorted(e.init_state for e in episodes if e.case) == [1, 3]
    assert sorted(e.init_state for e in episodes if e.case is None) == [1, 3]


def test_zero_cases_per_cell_plans_only_references_of_every_selected_task():
    episodes = plan([case("a")], cases_per_cell=0, libero_suites=["libero_goal"], init_states=[0, 2])
    assert all(e.case is None for e in episodes)
    assert {(e.task_id, e.init_state) for e in episodes} == {(t, s) for t in range(10) for s in (0, 2)}


def test_negative_cases_per_cell_is_a_user_error():
    with pytest.raises(UserError):
        plan([case("a")], cases_per_cell=-2)


def test_sample_is_seeded_bounded_per_cell_and_spans_suites():
    cases = [
        case(f"{s}-{t}-{f}-{level}", suite=s, task=t, family=f, level=level)
        for s in SUITES
        for t in range(3)
        for f in FAMILIES
        for level in LEVELS
    ]
    picked = sample_cases(cases, 4, seed=0)
    cells = Counter((c.family, c.level) for c in picked)
    assert set(cells.values()) == {4} and len(cells) == 16
    for cell in cells:  # 4 picks over 4 suites: one per suite
        assert len({c.suite for c in picked if (c.family, c.level) == cell}) == 4
    assert [c.case_id for c in sample_cases(cases, 4, seed=0)] == [c.case_id for c in picked]
    assert [c.case_id for c in sample_cases(cases, 4, seed=1)] != [c.case_id for c in picked]
    assert len(sample_cases(cases, 100, seed=0)) == len(cases)
    assert sample_cases(cases, None, seed=0) == sorted(cases, key=lambda c: c.case_id)


def test_plan_groups_episodes_by_base_task_references_first():
    cases = [case("x", suite="libero_10", task=3), case("y"), case("z", task=5)]
    episodes = plan(cases)
    keys = [e.task_key for e in episodes]
    assert keys == sorted(keys, key=lambda k: (k[0], k[1]))
    for key in set(keys):
        group = [e for e in episodes if e.task_key == key]
        assert group[0].case is None


def test_episode_ids_are_stable_and_change_with_anything_that_changes_the_rollout():
    spec = EpisodeSpec("libero_goal", 0, 0, "p0", "open the drawer")
    base = dict(policy="noop", config_hash="h", spec=spec, prompt_text="open the drawer", seed=7)
    eid = episode_id(**base)
    assert eid == episode_id(**base) and len(eid) == 24
    variants = [
        dict(policy="random"),
        dict(config_hash="h2"),
        dict(seed=8),
        dict(prompt_text="x"),
        dict(spec=EpisodeSpec("libero_goal", 0, 1, "p0", "open the drawer")),
        dict(spec=EpisodeSpec("libero_goal", 0, 0, "p1", "open the drawer")),
        dict(spec=EpisodeSpec("libero_goal", 0, 0, "p0", "open the drawer", case("a"))),
        dict(spec=EpisodeSpec("libero_goal", 0, 0, "p0", "open the drawer", case("a"), "conflictvla 2.1.0")),
    ]
    assert len({episode_id(**{**base, **v}) for v in variants} | {eid}) == len(variants) + 1


def test_a_conflict_episode_is_its_suites_and_the_plan_says_which():
    """A new suite version plays its cases again (a case's words may stay while its labels change); references,
    which no suite changes, keep their ids."""
    reference, conflict = plan([case("a", "libero_goal", 0)], conflict_suite="conflictvla 2.0.0")
    assert (reference.conflict_suite, conflict.conflict_suite) == ("", "conflictvla 2.0.0")


def test_a_policy_without_settings_hashes_as_it_always_has():
    """noop has no config: hashed as ``"config": null`` since the first store, so its episode ids never move."""
    import hashlib
    import json
    from dataclasses import dataclass

    from conflictbench.core import PolicyTraits
    from conflictbench.sim.plan import config_hash, identity_settings, settings_json, simulator_versions

    class Still:
        needs_images = False

    traits = PolicyTraits(Still())
    blob = {"policy": "noop", "config": None, "traits": traits.as_dict(), "code": [], "simulator": simulator_versions()}
    expected = hashlib.sha256(json.dumps(blob, sort_keys=True, default=repr).encode()).hexdigest()[:12]
    assert identity_settings(None) is None and config_hash("noop", None, traits) == expected
    assert settings_json(None) == "null"

    @dataclass
    class Served:
        identity_exempt = ("server",)
        server: str = "ws://a"
        seed: int = 3

    assert identity_settings(Served()) == {"seed": 3}  # the address is not the policy's identity
    assert config_hash("p", Served(), traits) == config_hash("p", Served(server="ws://b"), traits)


def test_a_declaration_added_later_leaves_the_identities_of_policies_without_it():
    """``needs_scene_state`` came after stores existed: at its default it is not hashed (every stored
    episode keeps its id); declared, it makes other episodes."""
    from conflictbench.core import PolicyTraits
    from conflictbench.sim.plan import config_hash

    class Still:
        needs_images = False

    class Seeing(Still):
        needs_scene_state = True

    plain = PolicyTraits(Still())
    assert set(plain.as_dict()) == {
        "needs_images", "needs_privileged", "image_size", "warmup_steps", "max_steps", "identity",
    }  # fmt: skip
    seeing = PolicyTraits(Seeing())
    assert seeing.as_dict()["needs_scene_state"] is True
    assert config_hash("p", None, plain) != config_hash("p", None, seeing)


def test_named_cases_play_exactly_those_whatever_the_sample_and_with_their_references():
    cases = [case("a"), case("b", level="L2"), case("c", suite="libero_10", task=4)]
    episodes = plan(cases, case_ids=["c", "a"], cases_per_cell=1, init_states=[2])
    assert sorted(e.case_id for e in episodes if e.case) == ["a", "c"]
    assert sorted((e.suite, e.task_id, e.init_state) for e in episodes if e.case is None) == [
        ("libero_10", 4, 2),
        ("libero_goal", 0, 2),
    ]


@pytest.mark.parametrize(
    ("case_ids", "filters", "message"),
    [
        (["spatial-L1-x"], {}, "no case 'spatial-L1-x' in the suite; the closest is spatial-L1-y"),
        (["zz"], {}, "no case 'zz' in the suite (ids look like a)"),
        (["gone"], {}, "case gone was removed by the suite's validation"),
        (["spatial-L1-y"], {"families": ["physical"]}, "spatial-L1-y (spatial L1, libero_goal/0) is outside"),
        (["a"], {"base_tasks": [("libero_10", 4)]}, "case a (physical L1, libero_goal/0) is outside"),
    ],
)
def test_a_named_case_that_cannot_play_is_one_line_saying_why(case_ids, filters, message):
    cases = [case("a"), case("spatial-L1-y", family="spatial"), case("gone", status="removed")]
    with pytest.raises(UserError, match=message.replace("(", r"\(").replace(")", r"\)")):
        plan(cases, case_ids=case_ids, **filters)


def test_named_base_tasks_keep_their_references_and_sampled_cases_only():
    cases = [case("a"), case("b", task=1), case("c", suite="libero_10", task=4)]
    episodes = plan(cases, base_tasks=[("libero_goal", 1), ("libero_10", 4)], cases_per_cell=None)
    assert sorted(e.case_id for e in episodes if e.case) == ["b", "c"]
    references = plan(cases, base_tasks=[("libero_goal", 1)], cases_per_cell=0, init_states=[0, 1])
    assert {(e.suite, e.task_id, e.init_state) for e in references} == {("libero_goal", 1, 0), ("libero_goal", 1, 1)}
    with pytest.raises(UserError, match="run.tasks names libero_10/4, outside run.libero_suites"):
        plan(
            cases,
            base_tasks=[("libero_10", 4)],
            base_instructions={k: v for k, v in BASE.items() if k[0] != "libero_10"},
        )
