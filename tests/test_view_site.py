"""The viewer's pages from a store (no simulator: ``--videos 0``); replays and a real browser: test_view_replay.py."""

import json
import re
from html.parser import HTMLParser

import numpy as np
import pytest

from conflictbench.cli import main
from conflictbench.core import EpisodeRecord, UserError
from conflictbench.metrics import evaluate_pairs
from conflictbench.store import EpisodeStore
from conflictbench.tasks.suite.file import load_suite
from conflictbench.view import Selection, build_site
from conflictbench.view.pairs import OUTCOMES, target_distance
from conflictbench.view.site import format_value, replay_words, script_json
from conflictbench.view.videos import FRAME_EVERY, episode_digest

SHIPPED = load_suite().cases


def episode(eid: str, *, case=None, success=True, h=6, seed=0, policy="noop", **kw) -> EpisodeRecord:
    rng = np.random.default_rng(seed)
    return EpisodeRecord(
        policy=policy,
        suite=case.suite if case else "libero_goal",
        task_id=case.task_id if case else 3,
        init_state=0,
        prompt=kw.pop("prompt", "p0"),
        instruction=case.instruction if case else "open the top drawer and put the bowl inside",
        case_id=case.case_id if case else None,
        family=case.family if case else None,
        level=case.level if case else None,
        episode_id=eid,
        success=success,
        steps=h,
        eef_pos=rng.normal(scale=0.1, size=(h + 1, 3)),
        target_pos=rng.normal(scale=0.1, size=(h + 1, 2, 3)),
        target_names=("akita_black_bowl_1", "wooden_cabinet_1_top_region"),
        actions=rng.normal(size=(h, 7)),
        raw_actions=rng.normal(size=(h, 7)),
        config_hash="c1",
        **kw,
    )


class Tags(HTMLParser):
    def __init__(self, text: str):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))


@pytest.fixture
def store(tmp_path):
    goal3 = [c for c in SHIPPED if (c.suite, c.task_id) == ("libero_goal", 3)]
    grounding = next(c for c in goal3 if c.family == "grounding")
    physical = next(c for c in goal3 if c.family == "physical")
    store = EpisodeStore(tmp_path / "results")
    store.write(episode("ref", seed=1))
    # ids that list physical first: the index's order (the paper's: grounding before physical) is another
    store.write(episode("c-phys", case=physical, success=True, seed=3))
    store.write(episode("d-ground", case=grounding, success=False, seed=2))
    store.write(episode("c-orphan", case=physical, prompt="p1", seed=4))  # no reference: not a pair
    return store, {"d-ground": grounding, "c-phys": physical}


def test_one_page_per_pair_with_its_texts_measures_and_plot_data(store, plugins, tmp_path):
    store, cases = store
    built = build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    assert (built.pairs, built.rendered) == (2, 0)
    assert sorted(p.name for p in (tmp_path / "site" / "pairs").iterdir()) == ["c-phys.html", "d-ground.html"]

    records = {r.episode_id: r for r in store.records()}
    ref, con = records["ref"], records["d-ground"]
    page = (tmp_path / "site" / "pairs" / "d-ground.html").read_text()
    case = cases["d-ground"]
    for text in (ref.instruction, con.instruction, case.premise, case.case_id, "qualified failure"):
        assert text.replace("'", "&#x27;") in page
    assert "No video rendered" in page and "<video" not in page  # --videos 0

    data = json.loads(re.search(r'<script type="application/json" id="pair-data">(.*?)</script>', page, re.S)[1])
    np.testing.assert_allclose(data["conflict"]["eef"], con.eef_pos, atol=5e-5)
    np.testing.assert_allclose(data["reference"]["actions"], ref.actions, atol=5e-4)
    np.testing.assert_allclose(data["conflict"]["distance"], target_distance(con), atol=5e-5)
    assert data["target_names"] == list(ref.target_names)

    assert shown_measures(page) == expected_measures(ref, con, plugins)


def shown_measures(page: str) -> dict[str, str]:
    return dict(re.findall(r"<tr><td>([^<]+)</td><td class='num'>(.*?)</td>", page))


BUILT_IN_LABELS = {"tar": "TAR", "early20_ts": "Early20 TS", "ts": "TS", "ams": "AMS"}


def expected_measures(reference, conflict, plugins) -> dict[str, str]:
    """Label -> shown value of every registered metric, in the registry's order (the page shows what is
    registered, an installed plugin's metrics too)."""
    row = evaluate_pairs([reference], [conflict], plugins=plugins).iloc[0]
    registered = plugins.metrics()
    assert set(BUILT_IN_LABELS) <= set(registered)
    return {BUILT_IN_LABELS.get(n, m.label or n): _expected_value(row[n], m) for n, m in registered.items()}


def _expected_value(value: float, metric) -> str:
    if metric.name not in BUILT_IN_LABELS:  # an installed plugin's, which this test cannot know: as reports show it
        return format_value(value, metric)
    return '<span class="undefined">undefined</span>' if np.isnan(value) else f"{100 * value:.1f} %"


def test_each_page_and_index_row_belongs_to_its_own_pair(store, plugins, tmp_path):
    store, cases = store
    build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    records = {r.episode_id: r for r in store.records()}
    index = (tmp_path / "site" / "index.html").read_text()
    links = re.findall(r'href="pairs/([^"]+)\.html"', index)
    assert links == ["d-ground", "c-phys"]  # the paper's order, not the store's
    rows = re.findall(r"<tr data-model.*?</tr>", index, re.S)
    for name, row in zip(links, rows, strict=True):
        conflict = records[name]
        expected = expected_measures(records["ref"], conflict, plugins)
        page = (tmp_path / "site" / "pairs" / f"{name}.html").read_text()
        assert f"noop · {conflict.family} {conflict.level} · p0" in page and cases[name].case_id in page
        assert shown_measures(page) == expected
        assert re.findall(r"<td class='num'>(.*?)</td>", row) == list(expected.values())
        assert f'data-family="{conflict.family}"' in row
    assert len({str(expected_measures(records["ref"], records[n], plugins)) for n in links}) == 2


def test_d_t_is_the_distance_to_the_nearest_target_at_each_state():
    record = episode("e", h=1)
    record.eef_pos = np.array([[0.0, 0, 0], [1, 1, 0]])
    record.target_pos = np.array([[[3.0, 4, 0], [0, 0, 2]], [[1, 1, 1], [9, 9, 9]]])
    np.testing.assert_allclose(target_distance(record), [2.0, 1.0])


def test_the_index_filters_by_model_family_level_prompt_and_outcome(store, plugins, tmp_path):
    store, cases = store
    build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    index = (tmp_path / "site" / "index.html").read_text()
    rows = [attrs for tag, attrs in Tags(index).tags if tag == "tr" and "data-family" in attrs]
    assert sorted((r["data-family"], r["data-outcome"]) for r in rows) == [
        ("grounding", OUTCOMES[(True, False)]),
        ("physical", OUTCOMES[(True, True)]),
    ]
    selects = {attrs["name"] for tag, attrs in Tags(index).tags if tag == "select"}
    assert selects == {"model", "family", "level", "prompt", "outcome"}
    assert all(r["data-model"] == "noop" and r["data-prompt"] == "p0" for r in rows)

    only = build_site(store.root, tmp_path / "site", plugins, Selection(family={"physical"}), videos=0, progress=False)
    assert only.pairs == 1  # into the same folder: the page of the pair it no longer shows goes
    assert [p.name for p in (tmp_path / "site" / "pairs").iterdir()] == ["c-phys.html"]


def test_filters_naming_nothing_are_refused_with_what_there_is(store, plugins, tmp_path):
    store, _ = store
    with pytest.raises(UserError, match=r"no pairs with family spatial.*there are: grounding, physical"):
        build_site(store.root, tmp_path / "site", plugins, Selection(family={"spatial"}), videos=0, progress=False)
    with pytest.raises(UserError, match="no pair matches"):
        selection = Selection(family={"grounding"}, outcome={OUTCOMES[(True, True)]})
        build_site(store.root, tmp_path / "site", plugins, selection, videos=0, progress=False)
    assert not (tmp_path / "site").exists()  # nothing written for a refused command


def test_the_command_names_mistakes_in_one_line(store, tmp_path, capsys):
    store, _ = store
    assert main(["view", str(tmp_path / "missing")]) == 2
    assert main(["view", str(store.root), "--videos", "some"]) == 2
    assert main(["view", str(store.root), "--level", "L9", "--videos", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("conflictbench: error:") for line in err)
    assert "L9" in err[2] and "Traceback" not in "".join(err)
    assert main(["view", str(store.root), "--videos", "0", "--no-progress"]) == 0
    assert (
        "2 pair pages, 1 reference episode page" in capsys.readouterr().out
        and (store.root / "view" / "index.html").is_file()
    )


def test_a_folder_the_site_cannot_go_to_is_named_in_one_line(store, tmp_path, capsys):
    store, _ = store
    (tmp_path / "a-file").write_text("")
    assert main(["view", str(store.root), "--videos", "0", "--out", str(tmp_path / "a-file")]) == 2
    assert main(["view", str(store.root), "--videos", "0", "--out", "/proc/no-site-here"]) == 2
    assert main(["view", str(store.root), "--videos", "0", "--pair", "nope"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert all(line.startswith("conflictbench: error:") for line in err) and len(err) == 3
    assert "it is a file" in err[0] and "/proc/no-site-here" in err[1] and "--pair nope" in err[2]


def test_a_video_shows_where_its_note_names_the_episode_as_stored_and_its_replay_worked(store, plugins, tmp_path):
    """Videos from an earlier build: shown on every page they belong to (not only the first N pairs'), never when
    the episode changed since, never when the replay failed."""
    store, _ = store
    site = tmp_path / "site"
    records = {r.episode_id: r for r in store.records()}

    def note(eid, **extra):
        meta = {"episode": episode_digest(records[eid]), "frame_every": FRAME_EVERY, "deviation_m": 0.0, **extra}
        (site / "videos").mkdir(parents=True, exist_ok=True)
        (site / "videos" / f"{eid}.json").write_text(json.dumps(meta))
        (site / "videos" / f"{eid}.mp4").write_bytes(b"video")

    for eid in ("ref", "d-ground", "c-phys"):
        note(eid)
    build_site(store.root, site, plugins, Selection(), videos=0, progress=False)
    assert pairs_table(site).count("<td>yes</td>") == 2
    assert (
        references_table(site).count("<td>yes</td>") == 1 and "<video" in (site / "episodes" / "ref.html").read_text()
    )
    assert all((site / "pairs" / f"{n}.html").read_text().count("<video") == 2 for n in ("d-ground", "c-phys"))

    note("c-phys", error="EGLError: could not make a context")
    changed = records["d-ground"]
    changed.actions = changed.actions + 1.0  # played again under the same id: the old video shows another rollout
    store.write(changed)
    build_site(store.root, site, plugins, Selection(), videos=0, progress=False)
    assert pairs_table(site).count("<td>yes</td>") == 0
    failed_page = (site / "pairs" / "c-phys.html").read_text()
    assert "The replay failed: EGLError" in failed_page and failed_page.count("<video") == 1  # the reference's
    assert (site / "pairs" / "d-ground.html").read_text().count("<video") == 1


def test_a_page_without_video_says_the_command_to_render_it_escaped(tmp_path, plugins):
    goal3 = next(c for c in SHIPPED if (c.suite, c.task_id) == ("libero_goal", 3))
    root = tmp_path / "r<img src=x onerror=alert(1)>"
    store = EpisodeStore(root)
    store.write(episode("ref", seed=1))
    store.write(episode("c1", case=goal3, seed=2))
    build_site(root, tmp_path / "site", plugins, Selection(), videos=0, progress=False,
               command=["conflictbench", "view", str(root), "--family", goal3.family])  # fmt: skip
    page = (tmp_path / "site" / "pairs" / "c1.html").read_text()
    assert "<img src=x" not in page and "&lt;img src=x onerror=alert(1)&gt;" in page
    assert f"--family {goal3.family} --pair c1" in page


def pairs_table(site) -> str:
    return (site / "index.html").read_text().split('<table id="pairs">')[1].split("</table>")[0]


def references_table(site) -> str:
    return (site / "index.html").read_text().split('<table id="references">')[1].split("</table>")[0]


def test_a_store_of_reference_episodes_alone_gets_a_page_for_each(tmp_path, plugins):
    """What `conflictbench reproduce` stores: the original instructions, no conflict, so no pair."""
    store = EpisodeStore(tmp_path / "r")
    store.write(episode("ref", seed=1))
    store.write(episode("ref2", seed=2, success=False))
    built = build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    assert (built.pairs, built.episodes) == (0, 2)
    rows = references_table(tmp_path / "site")
    assert rows.count("<tr>") == 3 and "succeeded" in rows and "failed" in rows  # a header and one row each
    page = (tmp_path / "site" / "episodes" / "ref2.html").read_text()
    assert "open the top drawer and put the bowl inside" in page and "No video rendered" in page
    assert "--videos all" in page
    by_model = build_site(store.root, tmp_path / "site2", plugins, Selection(model={"noop"}), videos=0, progress=False)
    assert by_model.episodes == 2  # the model filter names references too


def test_a_store_without_pairs_or_references_is_refused(tmp_path, plugins):
    store = EpisodeStore(tmp_path / "r")
    store.write(episode("c", case=SHIPPED[0]))  # a conflict episode whose reference is not stored
    with pytest.raises(UserError, match="no pairs and no reference episodes"):
        build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)


def test_the_page_says_whether_a_replay_retraced_the_stored_path():
    same, warning = replay_words({"deviation_m": 0.0})
    assert "equals the stored one" in same and not warning
    text, warning = replay_words({"deviation_m": 0.003})
    assert warning and "3.00 mm" in text
    assert replay_words({"deviation_m": float("inf")})[1] and replay_words({"error": "EGLError"})[1]
    assert replay_words(None) == ("", False)


def test_json_in_a_page_cannot_end_its_script_element():
    text = script_json({"instruction": "</script><b>x"})
    assert "</" not in text and json.loads(text) == {"instruction": "</script><b>x"}


def test_a_video_is_tied_to_the_episode_it_shows():
    a, b = episode("e", seed=1), episode("e", seed=1)
    assert episode_digest(a) == episode_digest(b)
    b.actions = b.actions.copy()
    b.actions[2, 0] += 1e-12  # the same episode id played again with other actions: its old video is stale
    assert episode_digest(a) != episode_digest(b)


def test_ctrl_c_says_the_finished_videos_are_kept(store, monkeypatch, capsys):
    store, _ = store

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("conflictbench.view.build_site", interrupted)
    assert main(["view", str(store.root)]) == 130
    err = capsys.readouterr().err
    assert "every finished video is kept" in err and "episode" not in err  # not the run's message


@pytest.mark.parametrize(
    ("policy", "settings"),
    [("noop", {}), ("random", {"seed": 3, "scale": 0.5}), ("subject", {"weights": "/my models/it's.npz"})],
)
def test_a_pages_play_again_command_plans_exactly_its_pair(plugins, policy, settings):
    import dataclasses
    import shlex

    from hydra import compose, initialize_config_module
    from hydra.core.global_hydra import GlobalHydra
    from omegaconf import OmegaConf

    from conflictbench.cli.run import register_model_configs, run_options
    from conflictbench.core import FAMILIES, LEVELS
    from conflictbench.sim.plan import build_plan
    from conflictbench.view.pairs import play_again_command

    case = next(c for c in SHIPPED if c.family == "spatial" and c.level == "L4" and c.suite == "libero_10")
    conflict = episode("x", case=case, policy=policy, prompt="p1", policy_settings=json.dumps(settings))
    conflict = dataclasses.replace(conflict, init_state=4, seed=11)
    words = shlex.split(play_again_command(conflict))
    assert words[0] == "conflictbench"
    register_model_configs(plugins)
    GlobalHydra.instance().clear()
    with initialize_config_module(config_module="conflictbench.conf", version_base=None):
        cfg = compose("config", overrides=words[1:])
    GlobalHydra.instance().clear()
    options = run_options(cfg.run)
    model = OmegaConf.to_container(cfg.model)
    assert {k: model[k] for k in settings} == settings and options.seed == 11
    base = {(s, t): f"task {s} {t}" for s in options.libero_suites for t in range(10)}
    plan = build_plan(
        SHIPPED, base_instructions=base, families=list(cfg.suite.families), levels=list(cfg.level.levels),
        prompts=list(cfg.prompt.conditions), init_states=options.init_states, cases_per_cell=options.cases_per_cell,
        libero_suites=options.libero_suites, case_ids=options.cases, base_tasks=options.tasks,
    )  # fmt: skip
    assert set(FAMILIES) == set(cfg.suite.families) and set(LEVELS) == set(cfg.level.levels)
    assert [(e.case_id, e.suite, e.task_id, e.init_state, e.prompt) for e in plan] == [
        (None, case.suite, case.task_id, 4, "p1"),
        (case.case_id, case.suite, case.task_id, 4, "p1"),
    ]


def test_a_spatial_pair_page_states_the_frame_and_draws_its_axes():
    """Suite 2.1: a spatial case's page says its directions are LIBERO's (the camera's) and whether
    they hold from the robot's side; the path seen from above has the axes named in that frame."""
    from importlib import resources

    from conflictbench.view.site import frame_of_reference

    spatial = [c for c in load_suite(None).cases if c.family == "spatial" and c.status != "removed"]
    dependent = next(c for c in spatial if c.witness["frame_independent"] is False)
    independent = next(c for c in spatial if c.witness["frame_independent"] is True)
    for case, said in ((dependent, "would be TRUE (frame dependent)"), (independent, "(frame independent)")):
        text = frame_of_reference(case)
        assert "front = towards the camera (+x)" in text and "left = -y" in text and said in text
    script = (resources.files("conflictbench.view") / "assets" / "viewer.js").read_text()
    assert 'compass: { x: "+x front (camera)", y: "+y image right = robot\'s left" }' in script


def test_a_policy_without_settings_gets_a_play_again_command():
    from conflictbench.view.pairs import play_again_command

    case = SHIPPED[0]
    record = episode("c", case=case, policy="noop", policy_settings="null")  # what the store holds for noop
    command = play_again_command(record)
    assert "model=noop" in command and "model." not in command.replace("model=noop", "")


def test_an_index_of_one_pair_says_one_pair(tmp_path, plugins):
    goal3 = next(c for c in SHIPPED if (c.suite, c.task_id) == ("libero_goal", 3))
    store = EpisodeStore(tmp_path / "r")
    store.write(episode("ref", seed=1))
    store.write(episode("c1", case=goal3, seed=2))
    build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    index = (tmp_path / "site" / "index.html").read_text()
    assert "<h1>conflictbench: 1 pair</h1>" in index and '<p id="count">1 pair</p>' in index


def test_the_replay_estimate_counts_frames_and_workers():
    from conflictbench.view.build import SECONDS_PER_FRAME, replay_estimate

    steps = [200] * 28  # the default slice's videos: 28 episodes of about 200 steps
    frames = 28 * 200 // FRAME_EVERY
    assert replay_estimate(steps, workers=2) == pytest.approx(frames * SECONDS_PER_FRAME / 2)
    assert replay_estimate(steps[:1], workers=4) == pytest.approx(
        200 // FRAME_EVERY * SECONDS_PER_FRAME
    )  # one at a time
    assert replay_estimate(steps, workers=2, per_frame=0.3) == pytest.approx(frames * 0.3 / 2)
    assert replay_estimate([], workers=2) == 0


def test_the_estimate_goes_by_what_a_frame_cost_the_sites_earlier_replays(tmp_path):
    from conflictbench.view.build import plan_line, seconds_per_frame

    out = tmp_path / "site"
    assert seconds_per_frame(out) is None
    assert "(about 8 s with 1 worker(s) on an idle CPU, longer under load)" in plan_line(1, 0, [100], 1, out)
    (out / "videos").mkdir(parents=True)
    notes = {"a": (200, 20.0, None), "b": (100, 10.0, None), "c": (100, 99.0, "the replay failed")}
    for name, (steps, seconds, error) in notes.items():
        meta = {"steps": steps, "frame_every": 2, "seconds": seconds, "error": error}
        (out / "videos" / f"{name}.json").write_text(json.dumps(meta))
    (out / "videos" / "torn.json").write_text("{")  # a note cut short is no basis
    assert seconds_per_frame(out) == pytest.approx(30.0 / 150)  # failed replays left out
    line = plan_line(1, 0, [100], 1, out)
    assert (
        "(about 10 s with 1 worker(s) at the 0.20 s a frame of this site's earlier replays, longer under load)" in line
    )


def test_the_plan_is_said_before_anything_is_built(store, plugins, tmp_path, capsys):
    store, _ = store
    build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    first = capsys.readouterr().err.splitlines()[0]
    assert first.startswith("conflictbench view: 2 pairs, 1 reference episode page, 0 episodes to replay")
