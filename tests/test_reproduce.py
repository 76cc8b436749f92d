"""``conflictbench reproduce``: the statistics, the declaration, and whole runs of LIBERO's standard evaluation
with stand-in policies of known success (noop never succeeds; the scripted expert completes libero_goal task 6)
against test-registered published figures chosen so that every verdict comes out of a real run."""

from __future__ import annotations

import json

import pytest

import conflictbench
from conflictbench import hookimpl
from conflictbench.cli import main
from conflictbench.core.plugins import Plugins
from conflictbench.report.reproduce import trials_to_decide, verdict, wilson
from conflictbench.store.declarations import declarations, record_declaration

PROTOCOL = {"episodes_per_suite": 500, "trials_per_task": 50, "init_states": "LIBERO's fixed 0-49", "warmup_steps": 10}


class StandIns:
    """Published figures for the built-in stand-ins (the figures are the test's, not anyone's paper)."""

    @hookimpl
    def conflictbench_register_published_results(self, register):
        figures = [("noop-ten", "noop", 10.0), ("noop-half", "noop", 50.0),
                   ("expert-high", "scripted", 95.0), ("expert-half", "scripted", 50.0)]  # fmt: skip
        for name, policy, percent in figures:
            register(name, policy=policy, checkpoint="(built in)", success={"libero_goal": percent},
                     protocol=PROTOCOL, source="test", url="https://example.org/t", date="2026-01-01",
                     played_by=["random"] if name == "noop-half" else [])  # fmt: skip


def stand_in_plugins() -> Plugins:
    return Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[StandIns()])


# -- the formulas, against hand-computed values ---------------------------------------------------------------
def test_wilson_interval_matches_hand_computed_values():
    # 8/10: centre (0.8 + 1.92073/10)/1.38415 = 0.71672, half 1.959964*sqrt(0.016 + 0.0096037)/1.38415 = 0.22658
    low, high = wilson(8, 10)
    assert (round(low, 4), round(high, 4)) == (0.4902, 0.9433)
    # 0/16: [0, z^2/(n+z^2)] = [0, 3.84146/19.84146]
    assert wilson(0, 16) == pytest.approx((0.0, 0.193607), abs=1e-6)
    assert wilson(16, 16) == pytest.approx((0.806393, 1.0), abs=1e-6)
    assert wilson(0, 0) == (0.0, 1.0)


def test_verdicts_follow_the_issue():
    assert verdict(0, 16, 10.0) == "consistent"  # 10 % inside [0, 19.4]
    assert verdict(0, 16, 50.0) == "below"
    assert verdict(16, 16, 50.0) == "above"
    assert verdict(16, 16, 95.0) == "consistent"
    assert verdict(0, 15, 50.0) == "inconclusive"  # half-width 10.2 points
    assert verdict(1, 2, 50.0) == "inconclusive"
    assert verdict(0, 0, 50.0) == "inconclusive"


def test_trials_to_decide_is_the_smallest_decisive_n():
    # at p=0 or 1 the half-width is z^2 / (2 (n + z^2)) <= 0.1  <=>  n >= 15.37
    assert trials_to_decide(0, 2, 50.0) == 16
    assert trials_to_decide(2, 2, 50.0) == 16
    # at p=0.5 the Wilson half-width reaches 0.1 first at n=93 (z^2/4 (1/n + z^2/(4 n^2)) <= 0.01 (1 + z^2/n)^2)
    assert trials_to_decide(1, 2, 50.0) == 93
    assert trials_to_decide(0, 0, 50.0) == 93  # no trials: at the published rate
    assert verdict(47, 93, 50.0) != "inconclusive" and verdict(46, 92, 50.0) == "inconclusive"


# -- the declaration ------------------------------------------------------------------------------------------
def test_declarations_merge_and_replace(tmp_path):
    assert declarations(tmp_path) == {}
    record_declaration(tmp_path, "pi05", "abc", "pi05-libero")
    record_declaration(tmp_path, "pi0", "def", "pi0-libero")
    record_declaration(tmp_path, "pi05", "abc", "pi05-libero-lerobot")
    assert declarations(tmp_path) == {("pi05", "abc"): "pi05-libero-lerobot", ("pi0", "def"): "pi0-libero"}
    assert not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["reproduce", "model=noop", "model.published=noop-tne"], "closest: noop-ten"),
        (["reproduce", "model=noop", "model.published=expert-high"], "is a published scripted checkpoint"),
        (["reproduce", "model=noop"], "reproduce needs model.published"),
        (["reproduce", "-m", "model=noop", "model.published=noop-ten"], "not a sweep"),
        (["model=noop,scripted", "model.published=noop-ten", "-m"], "not a sweep over models"),
        (["model=random", "model.published=noop-ten"], "not one of model=random's"),
        (["reproduce", "model=scripted", "model.published=noop-half"], "declare it with model=noop or model=random"),
        (["reproduce", "model=random", "model.published=noop-tne"], "closest: noop-half"),
    ],
)
def test_a_wrong_declaration_is_one_line_and_exit_2(monkeypatch, capsys, argv, says):
    monkeypatch.setattr(conflictbench, "plugins", lambda **kw: stand_in_plugins())
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1, err


def test_an_entry_another_policy_plays_as_its_source_did_is_declared_with_either():
    from conflictbench.cli.published import check_declaration

    plugins = stand_in_plugins()
    assert check_declaration("noop-half", "noop", plugins).name == "noop-half"
    assert check_declaration("noop-half", "random", plugins).played_by == ("random",)


# -- whole runs ------------------------------------------------------------------------------------------------
def reproduce(tmp_path, capsys, *args: str) -> str:
    from conflictbench.cli.reproduce import command

    capsys.readouterr()
    out = tmp_path / "store"
    argv = [*args, "run.tasks=[libero_goal/6]", "run.workers=1", "run.progress=false", f"run.out={out}",
            f"hydra.run.dir={tmp_path}/hydra"]  # fmt: skip
    assert command(argv, stand_in_plugins()) == 0
    return capsys.readouterr().out


def verdict_of(text: str, suite: str = "libero_goal") -> str:
    line = next(line for line in text.splitlines() if line.startswith(suite + " "))
    return line.split()[-1]


@pytest.mark.e2e  # costly (10-18 s): CI's marked lane plays it; the default selection stays under 10 min
@pytest.mark.sim
def test_noop_is_below_a_half_consistent_with_ten_and_quick_mode_is_inconclusive(tmp_path, capsys):
    store = tmp_path / "store"
    quick = reproduce(tmp_path, capsys, "model=noop", "model.published=noop-half", "--quick", "run.max_steps=3")
    assert verdict_of(quick) == "inconclusive"
    assert "libero_goal: inconclusive; 16 trials per suite would decide" in quick
    full = ["model=noop", "run.init_states=16", "run.max_steps=3"]
    below = reproduce(tmp_path, capsys, *full, "model.published=noop-half")
    assert verdict_of(below) == "below" and " 0.0 [  0.0,  19.4]" in below
    assert "16 episodes here; the published figure used 500 (50 per task)" in below
    assert "step budget 3 here, " not in below  # the test's protocol names no budget
    consistent = reproduce(tmp_path, capsys, *full, "model.published=noop-ten")  # the same episodes, reused
    assert verdict_of(consistent) == "consistent"
    assert (store / "report" / "reproduce-noop-ten.csv").read_text().splitlines()[1].startswith("libero_goal,16,0,0,")
    # one identity (the initial states are not part of it): the latest declaration stands
    assert list(declarations(store).values()) == ["noop-ten"]


@pytest.mark.sim
def test_the_plain_run_records_the_declaration_and_reproduce_reuses_its_episodes(tmp_path, capsys):
    from conflictbench.cli.run import command
    from conflictbench.store import EpisodeStore

    store = tmp_path / "store"
    common = ["run.tasks=[libero_goal/6]", "run.workers=1", "run.progress=false", "run.max_steps=3",
              "run.init_states=2", "run.cases_per_cell=0", "prompt=p0", "run.libero_suites=[libero_goal]",
              f"run.out={store}", f"hydra.run.dir={tmp_path}/hydra", "run.report=false"]  # fmt: skip
    assert command(["model=noop", "model.published=noop-ten", *common], stand_in_plugins()) == 0
    (declared,) = declarations(store).items()
    assert declared[0][0] == "noop" and declared[1] == "noop-ten"
    (row,) = json.loads((store / "declarations.json").read_text())
    stored = EpisodeStore(store).read_table(columns=["config_hash"]).column("config_hash").to_pylist()
    assert row["config_hash"] == declared[0][1] and set(stored) == {row["config_hash"]}  # the runner's column
    before = EpisodeStore(store).stored_ids()
    reproduce(tmp_path, capsys, "model=noop", "model.published=noop-half", "--quick", "run.max_steps=3")
    assert EpisodeStore(store).stored_ids() == before  # the same episodes: the declaration is no model setting
    assert declarations(store) == {declared[0]: "noop-half"}


@pytest.mark.sim
@pytest.mark.e2e
def test_the_viewer_opens_what_reproduce_stored(tmp_path, capsys):
    """What reproduce's last line promises: `conflictbench view` opens its episodes (one replayed to a video)."""
    from conflictbench.cli.view import command as view_command

    reproduce(tmp_path, capsys, "model=noop", "model.published=noop-half", "--quick", "run.max_steps=3")
    store = tmp_path / "store"
    assert view_command([str(store), "--videos", "1", "--no-progress"], stand_in_plugins()) == 0
    assert "0 pair pages, 2 reference episode pages, 1 video rendered" in capsys.readouterr().out
    pages = sorted((store / "view" / "episodes").glob("*.html"))
    assert len(pages) == 2 and sum("<video" in page.read_text() for page in pages) == 1


@pytest.mark.sim
@pytest.mark.e2e
def test_the_expert_is_above_a_half_and_consistent_with_95(tmp_path, capsys):
    above = reproduce(tmp_path, capsys, "model=scripted", "run.init_states=16", "model.published=expert-half")
    assert verdict_of(above) == "above" and " 16 " in above
    consistent = reproduce(tmp_path, capsys, "model=scripted", "run.init_states=16", "model.published=expert-high")
    assert verdict_of(consistent) == "consistent"


def test_every_shipped_entry_is_well_formed():
    """Each installed model plugin's published figures: suites, percentages, a citation (the registry checks the
    types; this says which entries there are)."""
    results = conflictbench.plugins().published_results()
    for name, result in results.items():
        assert set(result.success) <= {"libero_spatial", "libero_object", "libero_goal", "libero_10"}, name
        assert all(0 <= v <= 100 for v in result.success.values()), name
        assert result.url.startswith("https://") and result.date and result.source, name
        assert result.protocol["episodes_per_suite"] > 0, name
