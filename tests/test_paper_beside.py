"""The paper's figures beside a run's: only for a checkpoint declared as one of the paper's, only beside P0 rows,
marked as the paper's, and never part of a computation (issue 31, part 3)."""

from __future__ import annotations

import io
import re

import pandas as pd
import pytest
from test_report import two_models

import conflictbench
from conflictbench import hookimpl
from conflictbench.core.plugins import Plugins
from conflictbench.report import report_records
from conflictbench.report.paper import paper_models, paper_table, paper_value

DECLARED = {("alpha", "cfg"): "pi0.5"}


@pytest.fixture
def plugins():
    return conflictbench.plugins(entry_points=False)


def _report(records, plugins, tmp_path=None, paper=None) -> tuple[str, dict]:
    stream = io.StringIO()
    frames = report_records(records, plugins, stream=stream, figures=False, out_dir=tmp_path, paper=paper)
    return stream.getvalue(), frames


def _table(text: str, title: str) -> list[str]:
    block = text.split(f"== {title}")[1]
    return block.split("\n\n")[0].splitlines()


def test_the_shipped_tables_name_the_papers_eight_models_in_every_table():
    models = paper_models()
    assert len(models) == 8 and len(set(models)) == 8
    for table in ("table2_by_family", "table3_qualified_failures"):
        assert set(paper_table(table)["model"]) == set(models)
    assert set(paper_table("table2_by_family")["family"]) == {"instruction", "grounding", "spatial", "physical"}


def test_a_declared_models_p0_row_is_followed_by_the_papers_row_and_a_note(plugins):
    text, _ = _report(two_models(), plugins, paper=DECLARED)
    lines = _table(text, "Table 1")
    alpha = next(i for i, line in enumerate(lines) if line.startswith("alpha"))
    assert lines[alpha + 1].startswith("1 task ") and "[" in lines[alpha + 1]  # alpha's base tasks and intervals
    paper_row = lines[alpha + 2]
    assert paper_row.startswith("paper: pi0.5")
    pcsr = paper_value("table1_overall", "pi0.5", "PCSR")
    assert f"{pcsr:.1f} (paper)" in paper_row  # the shipped figure, shown as the paper's
    assert "*" not in paper_row  # never marked: it is not one of this run's rows
    assert sum(bool(re.match(r"paper: \S+ +p0 ", line)) for line in lines) == 1  # beta is not declared
    assert "the paper's suite is not this one" in text
    family = _table(text, "Table 2")
    rows = [line for line in family if line.startswith("paper: pi0.5")]
    assert len(rows) == 2  # grounding and spatial: the families alpha was measured in
    grounding = paper_value("table2_by_family", "pi0.5", "PCSR", "grounding")
    assert any("grounding" in r and f"{grounding:.1f} (paper)" in r for r in rows)
    failures = _table(text, "Table 3")
    fr = paper_value("table3_qualified_failures", "pi0.5", "FR")
    assert any(line.startswith("paper: pi0.5") and f"{fr:.1f} (paper)" in line for line in failures)


def test_the_papers_figures_enter_no_computation(plugins):
    _, plain = _report(two_models(), plugins)
    _, beside = _report(two_models(), plugins, paper=DECLARED)
    for name, frame in plain.items():
        pd.testing.assert_frame_equal(frame, beside[name])


def test_nothing_is_shown_for_an_undeclared_or_unknown_model(plugins):
    for paper in (None, {}, {("alpha", "cfg"): "not a paper model"}, {("alpha", "other-settings"): "pi0.5"}):
        text, _ = _report(two_models(), plugins, paper=paper)
        assert "paper:" not in text and "paper's suite" not in text


def test_p1_rows_get_no_paper_row(plugins):
    records = [r.__class__(**{**r.__dict__, "prompt": "p1", "episode_id": r.episode_id + "-p1"}) for r in two_models()]
    text, _ = _report(records, plugins, paper=DECLARED)
    assert "paper: pi0.5" not in text


def test_markdown_and_latex_files_carry_the_papers_rows_and_note(plugins, tmp_path):
    _report(two_models(), plugins, tmp_path=tmp_path, paper=DECLARED)
    markdown = (tmp_path / "table1_overall.md").read_text()
    pcsr = paper_value("table1_overall", "pi0.5", "PCSR")
    assert re.search(rf"\| paper: pi0\.5 .*\| +{pcsr:.1f} \(paper\) \|", markdown)
    assert "the paper's suite is not this one" in markdown
    latex = (tmp_path / "table1_overall.tex").read_text()
    assert "paper: pi0.5" in latex and "(paper)" in latex and "not this one" in latex
    csv = pd.read_csv(tmp_path / "table1_overall.csv")
    assert not csv["model"].astype(str).str.startswith("paper").any()  # the CSV holds this run's numbers only


def test_a_metric_the_paper_lacks_is_left_blank_in_the_papers_row():
    assert paper_value("table1_overall", "pi0.5", "my_plugin_metric") is None
    assert paper_value("table2_by_family", "pi0.5", "early20_ts", "grounding") is None  # table 2 has no Early20
    assert paper_value("table3_qualified_failures", "pi0.5", "tar_qf") == float(
        paper_table("table3_qualified_failures").set_index("model").loc["pi0.5", "TAR"]
    )


class PaperCheckpoint:
    """A published entry declared to be the paper's pi0 (the figures are the test's; the plugin says so)."""

    @hookimpl
    def conflictbench_register_published_results(self, register):
        for name, paper_model in (("official-pi0", "pi0"), ("someone-elses", None)):
            register(name, policy="noop", checkpoint="(built in)", success={"libero_goal": 50.0},
                     protocol={"episodes_per_suite": 500}, source="test", url="https://example.org/t",
                     date="2026-01-01", paper_model=paper_model)  # fmt: skip


@pytest.mark.e2e  # costly (10-18 s): CI's marked lane plays it; the default selection stays under 10 min
@pytest.mark.sim
def test_a_declared_run_shows_the_papers_rows_at_its_end_in_its_report_and_on_the_viewers_index(tmp_path, capsys):
    from conflictbench.cli.report import command as report_command
    from conflictbench.cli.run import command as run_command
    from conflictbench.cli.view import command as view_command

    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[PaperCheckpoint()])
    store = tmp_path / "store"
    common = ["model=noop", "run.tasks=[libero_goal/6]", "run.workers=1", "run.progress=false", "run.max_steps=3",
              "suite=grounding", "level=L1", f"run.out={store}", f"hydra.run.dir={tmp_path}/hydra"]  # fmt: skip
    pcsr = f"{paper_value('table1_overall', 'pi0', 'PCSR'):.1f} (paper)"
    assert run_command([*common, "model.published=someone-elses"], plugins) == 0
    assert "paper:" not in capsys.readouterr().out  # a declared checkpoint that is not one of the paper's: nothing
    assert run_command([*common, "model.published=official-pi0"], plugins) == 0
    assert re.search(rf"\npaper: pi0 +p0 .*{re.escape(pcsr)}", capsys.readouterr().out)  # the run's own summary
    assert report_command([str(store)], plugins) == 0
    assert re.search(rf"\npaper: pi0 +p0 .*{re.escape(pcsr)}", capsys.readouterr().out)
    assert "paper: pi0" in (store / "report" / "table1_overall.md").read_text()
    assert view_command([str(store), "--videos", "0", "--no-progress"], plugins) == 0
    index = (store / "view" / "index.html").read_text()
    assert "Beside the paper (P0)" in index and "paper: pi0" in index and pcsr in index
    assert "the paper&#x27;s suite is not this one" in index or "the paper's suite is not this one" in index
