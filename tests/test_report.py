"""The report: the paper's tables and figures from a real Parquet store, plugin metrics, empty subsets."""

from __future__ import annotations

import io
import math
import subprocess
import sys

import pandas as pd
import pytest
from testing_support import in_tasks
from testing_support import report_episode as episode

import conflictbench
from conflictbench.cli.report import command as report_command
from conflictbench.core import EpisodeRecord, Plugins, hookimpl
from conflictbench.report import report_records
from conflictbench.store import EpisodeStore

PNG = b"\x89PNG\r\n\x1a\n"


def two_models() -> list[EpisodeRecord]:
    # Both references go 0.5 -> 0.1 (A+ = 0.4) moving 0.2 (I+ = 1) and succeed.
    # alpha/c1 fails: 0.5 -> 0.3, move 0.1: TAR 0.5, AMS 0.5, DTW: diagonal 0 + 0.2 over 2 cells
    #   -> TS = exp(-0.2 / (0.1 * 2)) = exp(-1)
    # alpha/c2 succeeds, same as the reference: TAR 1, TS 1, AMS 0
    # beta/c1 and beta/c2 fail and stay at 0.5 without moving: TAR 0, AMS 1; costs c00 = 0,
    #   c11 = 0.4, c10 = 0: diagonal 0.4 (2 cells) ties with (0,0)->(1,0)->(1,1) (3 cells): L = 2
    #   -> TS = exp(-0.4 / 0.2) = exp(-2)
    return [
        episode("alpha", None, 0.1, 0.2, True, steps=40),
        episode("alpha", "c1", 0.3, 0.1, False, "grounding", "L1", steps=10),
        episode("alpha", "c2", 0.1, 0.2, True, "spatial", "L2", steps=20),
        episode("beta", None, 0.1, 0.2, True, steps=40),
        episode("beta", "c1", 0.5, 0.0, False, "grounding", "L1", steps=40),
        episode("beta", "c2", 0.5, 0.0, False, "spatial", "L2", steps=40),
    ]


@pytest.fixture
def plugins():
    return conflictbench.plugins(entry_points=False)


def stored(tmp_path, records) -> list[EpisodeRecord]:
    store = EpisodeStore(tmp_path / "run")
    for r in records:
        store.write(r)
    return EpisodeStore(tmp_path / "run").records()


def test_tables_from_a_parquet_store_match_hand_counts(tmp_path, plugins):
    records = stored(tmp_path, two_models())
    assert len(records) == 6
    out = io.StringIO()
    frames = report_records(records, plugins, out_dir=tmp_path / "report", stream=out)
    t1 = pd.read_csv(tmp_path / "report" / "table1_overall.csv").set_index("model")
    for column in ("PCSR", "RGSR", "dSR", "TAR", "Early20 TS", "TS", "AMS"):  # the paper's layout, registered labels
        assert column in t1.columns
    alpha, beta = t1.loc["alpha"], t1.loc["beta"]
    assert (alpha["PCSR"], alpha["PCSR_k"], alpha["PCSR_n"]) == (100.0, 2, 2)
    assert (alpha["RGSR"], alpha["RGSR_k"], beta["RGSR"], beta["RGSR_k"]) == (50.0, 1, 0.0, 0)
    assert (alpha["dSR"], beta["dSR"]) == (50.0, 100.0)
    assert alpha["TAR"] == pytest.approx(75.0) and beta["TAR"] == 0.0
    assert alpha["TS"] == pytest.approx(100 * (math.exp(-1) + 1) / 2)
    assert beta["TS"] == pytest.approx(100 * math.exp(-2)) and beta["Early20 TS"] == pytest.approx(100 * math.exp(-2))
    assert alpha["AMS"] == pytest.approx(25.0) and beta["AMS"] == pytest.approx(100.0) and beta["AMS_n"] == 2

    t3 = pd.read_csv(tmp_path / "report" / "table3_qualified_failures.csv").set_index("model")
    assert list(t3.columns[:8]) == ["prompt", "tasks", "FR", "FR_lo", "FR_hi", "FR_k", "FR_n", "FR_clusters"]
    # one base task: nothing measures how tasks differ, so the interval is the whole range
    assert (t3.loc["alpha", "tasks"], t3.loc["alpha", "FR_lo"], t3.loc["alpha", "FR_hi"]) == (1, 0.0, 100.0)
    assert (t3.loc["alpha", "FR"], t3.loc["alpha", "FR_k"], t3.loc["alpha", "FR_n"]) == (50.0, 1, 2)
    assert t3.loc["beta", "FR"] == 100.0
    # over D_QF only: alpha's qualified failure is c1 alone
    assert t3.loc["alpha", "TAR"] == pytest.approx(50.0) and t3.loc["alpha", "TAR_n"] == 1
    assert t3.loc["alpha", "TS"] == pytest.approx(100 * math.exp(-1))

    t2 = pd.read_csv(tmp_path / "report" / "table2_by_family.csv")
    assert list(t2["family"]) == ["grounding", "spatial", "grounding", "spatial"]
    spatial_alpha = t2[(t2["model"] == "alpha") & (t2["family"] == "spatial")].iloc[0]
    assert (spatial_alpha["RGSR"], spatial_alpha["TAR"]) == (100.0, 100.0)

    text = out.getvalue()
    assert "Table 1" in text and "Table 2" in text and "Table 3" in text
    assert "50.0 (1/2)" in text and "100.0 (2/2)" in text  # rates with their counts
    assert "6 episodes (2 reference, 4 conflict), 4 pairs" in text
    assert len(frames["pairs"]) == 4


def test_most_favourable_values_are_marked_where_a_paired_comparison_tells_them_apart(tmp_path, plugins):
    out = io.StringIO()
    report_records(in_tasks(two_models(), 20), plugins, out_dir=tmp_path, stream=out, figures=False)
    rows = {}
    for line in out.getvalue().splitlines():
        if line.startswith(("alpha ", "beta ")):
            rows.setdefault(line.split()[0], line)
    # table 1 is printed first: in each of 20 base tasks beta has the lower RGSR and TAR, the higher dSR and AMS;
    # both have PCSR 100: a tie marks nothing, and is no value left unmarked
    beta, alpha = rows["beta"], rows["alpha"]
    assert "0.0 (0/40)*" in beta and "100.0 (n=40)*" in beta
    assert "*" not in alpha
    assert "100.0 (40/40)*" not in beta
    table1 = out.getvalue().split("== Table 2")[0]
    assert "not marked" not in table1
    md = (tmp_path / "table1_overall.md").read_text()
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in md.splitlines() if line.startswith("|")]
    beta_cells = next(c for c in cells if c[0] == "beta")
    assert beta_cells[:4] == ["beta", "p0", "20", "100.0 [82.0, 100.0] (40/40)"]  # nothing differs: 0 of 20 tasks
    assert beta_cells[4].startswith("**0.0 [0.0, ") and beta_cells[4].endswith("] (0/40)**")
    assert cells[1][1].startswith(":-") and cells[1][3].endswith("-:")  # keys left, values right
    tex = (tmp_path / "table1_overall.tex").read_text()
    assert r"\textbf{0.0}\,{\scriptsize [0.0, " in tex and r"\begin{tabular}" in tex


def test_a_best_value_a_paired_comparison_cannot_tell_apart_is_not_marked_and_the_note_says_so(tmp_path, plugins):
    out = io.StringIO()
    report_records(two_models(), plugins, out_dir=tmp_path, stream=out, figures=False)  # one base task
    table1 = out.getvalue().split("== Table 2")[0]
    assert "*" not in table1.split("\n", 4)[-1].split("rates and means")[0]  # no value of the rows is marked
    assert "not marked: RGSR, dSR, TAR, Early20 TS, TS, AMS (in some prompt condition" in table1
    md = (tmp_path / "table1_overall.md").read_text()
    assert "**" not in md and "not marked: RGSR, dSR" in md


def test_figures_are_written_as_png(tmp_path, plugins):
    records = two_models()
    records += [episode("alpha", None, 0.1, 0.2, True, steps=40, init=1)]
    records += [r for r in (episode("alpha", "c1", 0.2, 0.1, False, "grounding", "L1", init=1),)]
    p1 = [EpisodeRecord(**{**r.__dict__, "prompt": "p1", "episode_id": r.episode_id + "-p1"}) for r in records]
    report_records(records + p1, plugins, out_dir=tmp_path, stream=io.StringIO())
    for name in ("fig_qf_distributions.png", "fig_prompt_differences.png", "fig_dsr_heatmap.png", "fig_outcomes.png"):
        data = (tmp_path / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 10_000
    differences = pd.read_csv(tmp_path / "prompt_differences.csv")
    assert list(differences["pairs"]) == [3, 2]  # alpha: c1 x 2 states + c2; beta: c1, c2
    assert list(differences["RGSR"]) == [0.0, 0.0]  # the same outcomes under both prompts
    assert list(differences["RGSR_p"]) == [1.0, 1.0]


def test_the_outcome_figure_draws_each_rate_with_its_counts_and_says_na_where_nothing_was_played(plugins):
    from conflictbench.metrics import aggregate, with_model
    from conflictbench.report.figures import outcome_figure

    frame = with_model(report_records(two_models(), plugins, stream=io.StringIO())["pairs"])
    figure = outcome_figure(aggregate(frame, ("model", "prompt", "family", "level"), []))
    panels = {ax.get_title(): ax for ax in figure.axes}
    assert list(panels) == ["instruction P0", "grounding P0", "spatial P0", "physical P0"]
    texts = {title: [t.get_text() for t in ax.texts] for title, ax in panels.items()}
    assert texts["instruction P0"] == ["n/a (n=0)"] and texts["physical P0"] == ["n/a (n=0)"]
    # grounding L1: alpha and beta each PCSR 1/1 (100 %) and RGSR 0/1; no pair at L2-L4
    assert sorted(t for t in texts["grounding P0"] if t[:1].isdigit()) == ["0/1", "0/1", "1/1", "1/1"]
    assert texts["grounding P0"].count("n/a") == 12  # 2 models x 2 rates x 3 levels
    heights = sorted(round(bar.get_height()) for bar in panels["grounding P0"].patches)
    assert heights == [0, 0, 100, 100]
    empty = outcome_figure(aggregate(frame.iloc[:0], ("model", "prompt", "family", "level"), []))
    assert all(ax.texts[0].get_text() == "n/a (n=0)" for ax in empty.axes)


class StepRatio:
    @hookimpl
    def conflictbench_register_metrics(self, register):
        register(
            "step_ratio",
            compute=lambda pair: pair.conflict.steps / pair.reference.steps,
            description="conflict steps / reference steps",
        )


def test_a_plugin_metric_appears_beside_the_builtins(tmp_path):
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[StepRatio()])
    records = stored(tmp_path, two_models())
    out = io.StringIO()
    report_records(records, plugins, out_dir=tmp_path / "report", stream=out)
    t1 = pd.read_csv(tmp_path / "report" / "table1_overall.csv").set_index("model")
    # alpha: 10/40 and 20/40 -> 0.375 (a plugin metric keeps its own units); beta: 1.0
    assert list(t1.columns).index("step_ratio") > list(t1.columns).index("AMS")
    assert t1.loc["alpha", "step_ratio"] == pytest.approx(0.375) and t1.loc["alpha", "step_ratio_n"] == 2
    assert t1.loc["beta", "step_ratio"] == pytest.approx(1.0)
    t3 = pd.read_csv(tmp_path / "report" / "table3_qualified_failures.csv").set_index("model")
    assert t3.loc["alpha", "step_ratio"] == pytest.approx(0.25)  # D_QF: c1 only
    assert "step_ratio" in pd.read_csv(tmp_path / "report" / "pairs.csv").columns
    assert "0.375 (n=2)" in out.getvalue()


def test_empty_subsets_read_na_with_counts(tmp_path, plugins):
    # gamma's reference failed: D_Q is empty, so FR and every mean over D_QF are n/a
    records = two_models() + [
        episode("gamma", None, 0.5, 0.0, False),
        episode("gamma", "c1", 0.5, 0.0, False, "physical", "L3"),
    ]
    out = io.StringIO()
    report_records(records, plugins, out_dir=tmp_path, stream=out)
    gamma = [line for line in out.getvalue().splitlines() if line.startswith("gamma")]
    table3 = gamma[-1]
    assert "n/a (0/0)" in table3 and table3.count("n/a (n=0)") == 4
    assert "nan" not in out.getvalue().lower()
    t3 = pd.read_csv(tmp_path / "table3_qualified_failures.csv").set_index("model")
    assert math.isnan(t3.loc["gamma", "FR"]) and t3.loc["gamma", "FR_n"] == 0
    assert "n/a" in (tmp_path / "table3_qualified_failures.csv").read_text()


def test_no_pairs_at_all_still_reports(tmp_path, plugins):
    out = io.StringIO()
    frames = report_records([episode("alpha", None, 0.1, 0.2, True)], plugins, out_dir=tmp_path, stream=out)
    assert "n/a" in out.getvalue() and "0 pairs" in out.getvalue()
    assert frames["overall"].empty
    assert (tmp_path / "table1_overall.md").exists() and (tmp_path / "fig_dsr_heatmap.png").exists()


def test_pairs_whose_reference_did_not_approach_leave_tar_undefined_and_are_counted(plugins, tmp_path):
    records = [episode("gamma", None, 0.5, 0.2, False), episode("gamma", "c1", 0.3, 0.1, False, "grounding", "L1")]
    stream = io.StringIO()
    result = report_records(records, plugins, stream=stream)  # the reference stood at 0.5: A+ = 0
    assert result["pairs"]["tar"].isna().all() and result["pairs"]["ts"].notna().all()
    assert "TAR is undefined for 1 of 1 pairs: 1 whose reference approached its targets by less than 1 cm" in (
        stream.getvalue()
    )
    report_records(records, plugins, stream=io.StringIO(), out_dir=tmp_path, figures=False)
    written = (tmp_path / "report.md").read_text()
    assert "TAR is undefined for 1 of 1 pairs" in written and "### Legend" in written and "  RGSR  " in written
    assert "TAR is undefined" not in _report_text(two_models(), plugins)


def test_the_two_causes_of_an_undefined_tar_are_counted_apart(plugins):
    still = episode("gamma", "c1", 0.5, 0.1, False, "grounding", "L1")  # its reference stood still: A+ = 0
    other = episode("gamma", "c2", 0.3, 0.1, False, "grounding", "L1", init=1)
    other.target_names = ("ketchup_1",)  # the conflict rollout was scored against another object
    records = [episode("gamma", None, 0.5, 0.2, False), still, episode("gamma", None, 0.1, 0.2, True, init=1), other]
    stream = io.StringIO()
    result = report_records(records, plugins, stream=stream)
    assert result["pairs"]["tar"].isna().all() and list(result["pairs"]["same_targets"]) == [True, False]
    assert (
        "TAR is undefined for 2 of 2 pairs: 1 whose reference approached its targets by less than 1 cm (a ratio to "
        "that is noise); 1 whose two rollouts have other targets"
    ) in stream.getvalue()


def test_the_tables_come_with_a_legend_of_every_column(plugins):
    text = _report_text(two_models(), plugins)
    legend = text.split("Legend\n", 1)[1].split("\n\n", 1)[0].splitlines()
    names = [line.split()[0] for line in legend]
    assert names[:4] == ["PCSR", "RGSR", "dSR", "FR"] and {"TAR", "TS", "AMS", "Early20"} <= set(names)
    tar = next(line for line in legend if line.split()[0] == "TAR")
    assert tar.split(None, 1)[1] == (
        "how far the conflict rollout still closed in on the original targets, relative to the reference"
    )


def _report_text(records, plugins) -> str:
    stream = io.StringIO()
    report_records(records, plugins, stream=stream)
    return stream.getvalue()


def test_policy_errors_count_as_failures_and_simulator_failures_are_left_out(plugins):
    from conflictbench.core import SIMULATOR_ERROR_PREFIX

    crashed = episode("alpha", "c3", 0.5, 0.0, False, "physical", "L1", error=f"{SIMULATOR_ERROR_PREFIX}: died")
    broke = episode("alpha", "c4", 0.5, 0.0, False, "physical", "L1", error="policy returned NaN")
    others = [  # typed failures: their kind decides, whatever the text
        episode("alpha", f"c{5 + i}", 0.5, 0.0, False, "physical", "L1", error="it failed", error_kind=kind)
        for i, kind in enumerate(("server", "plugin", "server", "client", "policy"))
    ]
    out = io.StringIO()
    frames = report_records(two_models() + [crashed, broke, *others], plugins, stream=out)
    pairs = frames["pairs"]
    assert len(pairs) == 6 and set(pairs["case_id"]) == {"c1", "c2", "c4", "c9"}
    assert not pairs.loc[pairs["case_id"] == "c4", "conflict_success"].item()
    text = out.getvalue()
    assert "2 episode(s) ended with a policy error and count as failed" in text
    assert (
        "5 episode(s) left out, with their pairs, and played again by the next run: 1 plugin, 1 client, 2 server, "
        "1 simulator (e.g. " in text
    )


def test_report_into_a_closed_pipe_still_writes_its_files(tmp_path):
    """`report DIR | head` (here `| true`, which has exited before anything is printed): the tables are written
    first, and the closed pipe ends the command quietly."""
    stored(tmp_path, two_models())
    command = f"set -o pipefail; {sys.executable} -m conflictbench.cli report {tmp_path / 'run'} | true"
    done = subprocess.run(command, shell=True, executable="/bin/bash", capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr[-2000:]
    assert (tmp_path / "run" / "report" / "table1_overall.csv").is_file()


def test_report_verb_reads_a_store_directory(tmp_path, plugins, capsys):
    stored(tmp_path, two_models())
    assert report_command([str(tmp_path / "run"), "--metrics", "ts,ams"], plugins) == 0
    t1 = pd.read_csv(tmp_path / "run" / "report" / "table1_overall.csv")
    assert "TS" in t1.columns and "TAR" not in t1.columns
    assert "Table 1" in capsys.readouterr().out


def test_a_report_shows_the_current_suites_conflict_episodes_and_counts_the_others(tmp_path, plugins, capsys):
    """A store keeps episodes of earlier suite versions (a new version plays its cases again): by default the report
    is the shipped suite's and says what it did not show; --all-suites shows every one."""
    from dataclasses import replace

    from conflictbench.tasks.suite.file import load_suite

    current = load_suite().label
    records = [
        replace(r, conflict_suite=None if r.is_reference else current if r.policy == "alpha" else "conflictvla 1.0.0")
        for r in two_models()
    ]
    stored(tmp_path, records)
    assert report_command([str(tmp_path / "run")], plugins) == 0
    shown = pd.read_csv(tmp_path / "run" / "report" / "pairs.csv")
    assert sorted(set(shown["model"])) == ["alpha"]
    said = capsys.readouterr().out
    assert (
        "conflict episodes not shown: 2 of suite conflictvla 1.0.0 (conflictbench report --all-suites shows them)"
        in said
    )
    # which of those cases the shipped suite no longer plays: named, and listed in full beside the tables
    gone = sorted({r.case_id for r in records if r.policy == "beta" and not r.is_reference})
    playing = {c.case_id for c in load_suite().cases if c.status != "removed"}
    assert gone and not set(gone) & playing
    listed = tmp_path / "run" / "report" / "cases_no_longer_in_suite.txt"
    assert f"of them, {len(gone)} case(s) are no longer in suite {current}: {', '.join(gone)} (all in {listed})" in said
    assert listed.read_text().split() == gone
    assert report_command([str(tmp_path / "run"), "--all-suites"], plugins) == 0
    assert sorted(set(pd.read_csv(tmp_path / "run" / "report" / "pairs.csv")["model"])) == ["alpha", "beta"]
    assert "not shown" not in capsys.readouterr().out


def test_conflict_episodes_stored_before_the_suite_was_recorded_are_shown_and_said_so(tmp_path, plugins, capsys):
    stored(tmp_path, two_models())  # no conflict_suite: a store written before the column
    assert report_command([str(tmp_path / "run")], plugins) == 0
    assert sorted(set(pd.read_csv(tmp_path / "run" / "report" / "pairs.csv")["model"])) == ["alpha", "beta"]
    assert "4 conflict episode(s) were stored before their suite was recorded and are shown as this suite's" in (
        capsys.readouterr().out
    )


def test_one_of_a_thing_is_counted_in_the_singular(plugins):
    records = [episode("gamma", None, 0.1, 0.2, True), episode("gamma", "c1", 0.3, 0.1, False, "grounding", "L1")]
    text = _report_text(records, plugins)
    assert "2 episodes (1 reference, 1 conflict), 1 pair\n" in text


def test_a_report_can_leave_its_legend_to_another_but_its_files_keep_it(plugins, tmp_path):
    """A sweep's jobs: the legend is printed once, with the combined report."""
    stream = io.StringIO()
    report_records(two_models(), plugins, stream=stream, out_dir=tmp_path, figures=False, print_legend=False)
    assert "Legend\n" not in stream.getvalue() and "== Table 1" in stream.getvalue()
    assert "### Legend" in (tmp_path / "report.md").read_text()
