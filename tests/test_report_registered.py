"""The report shows every metric as its registration says (label, unit, direction), built-ins and
plugins alike, and only the metrics the registry holds."""

from __future__ import annotations

import io

import pandas as pd
import pytest
from testing_support import in_tasks, report_episode

import conflictbench
from conflictbench.core import EpisodeRecord, Plugins, UserError, hookimpl
from conflictbench.report import report_records


def episode(policy: str, case: str | None, steps: int, success: bool, family: str | None = None) -> EpisodeRecord:
    return report_episode(policy, case, 0.3, 0.1, success, family, "L1" if case else None, steps=steps)


def records() -> list[EpisodeRecord]:
    # steps of conflict / reference: alpha 10/40 and 20/40 (mean 0.375), beta 40/40 twice (1.0)
    return [
        episode("alpha", None, 40, True),
        episode("alpha", "c1", 10, False, "grounding"),
        episode("alpha", "c2", 20, True, "spatial"),
        episode("beta", None, 40, True),
        episode("beta", "c1", 40, False, "grounding"),
        episode("beta", "c2", 40, False, "spatial"),
    ]


def step_ratios(references, conflicts):
    return [c.steps / r.steps for r, c in zip(references, conflicts)]


class PathRatio:
    """Batched only, shown as a percentage, lower is better."""

    @hookimpl
    def conflictbench_register_metrics(self, register):
        register("path_ratio", compute_many=step_ratios, label="Path ratio", unit="%", higher_is_better=False)


class Plain:
    """Pair by pair, in its own unit, with LaTeX specials in its label, no direction."""

    @hookimpl
    def conflictbench_register_metrics(self, register):
        register(
            "steps_left",
            compute=lambda pair: (pair.reference.steps - pair.conflict.steps) / 100,
            label="Left_over & #",
            unit="m",
        )


def table_lines(text: str, model: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith(model + " ")]


def test_a_plugin_metric_shows_with_its_label_as_a_percentage_and_marked_where_lowest(tmp_path):
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[PathRatio()])
    out = io.StringIO()
    played = in_tasks(records(), 8)  # the same pairs in 8 base tasks: a paired comparison tells them apart
    report_records(played, plugins, out_dir=tmp_path, stream=out, figures=False)
    t1 = pd.read_csv(tmp_path / "table1_overall.csv").set_index("model")
    assert list(t1.columns)[-5:] == ["Path ratio", "Path ratio_lo", "Path ratio_hi", "Path ratio_n",
                                     "Path ratio_clusters"]  # after the built-ins  # fmt: skip
    assert t1.loc["alpha", "Path ratio"] == pytest.approx(37.5) and t1.loc["beta", "Path ratio"] == 100.0
    assert t1.loc["alpha", "Path ratio_lo"] < 37.5 < t1.loc["alpha", "Path ratio_hi"] < 100.0
    alpha, beta = table_lines(out.getvalue(), "alpha")[0], table_lines(out.getvalue(), "beta")[0]
    assert alpha.endswith("37.5 (n=16)*") and beta.endswith("100.0 (n=16)")
    assert "Path ratio" in out.getvalue().splitlines()[2]  # the header row
    assert "lower RGSR, TAR, Early20 TS, TS, Path ratio" in out.getvalue()  # the legend
    md = (tmp_path / "table1_overall.md").read_text()
    last = {
        c[0]: c[-1]
        for c in (
            [x.strip() for x in line.strip("|").split("|")]
            for line in md.splitlines()
            if line.startswith("| alpha") or line.startswith("| beta")
        )
    }
    low, high = t1.loc["alpha", "Path ratio_lo"], t1.loc["alpha", "Path ratio_hi"]
    assert last == {"alpha": f"**37.5 [{low:.1f}, {high:.1f}] (n=16)**", "beta": "100.0 [58.9, 100.0] (n=16)"}
    tex = (tmp_path / "table1_overall.tex").read_text()
    assert r"Path ratio \\" in tex and rf"\textbf{{37.5}}\,{{\scriptsize [{low:.1f}, {high:.1f}] (n=16)}}" in tex
    # a direction given to the report overrides the registered one
    flipped = io.StringIO()
    report_records(played, plugins, stream=flipped, figures=False, directions={"path_ratio": "higher"})
    assert table_lines(flipped.getvalue(), "beta")[0].endswith("100.0 (n=16)*")


def test_a_metric_in_its_own_unit_without_a_direction_is_shown_as_measured_and_unmarked(tmp_path):
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[Plain()])
    out = io.StringIO()
    report_records(records(), plugins, out_dir=tmp_path, stream=out, figures=True)
    # alpha: (40 - 10) / 100 and (40 - 20) / 100 -> 0.25 m; beta: 0 m
    assert table_lines(out.getvalue(), "alpha")[0].endswith("0.25 m (n=2)")
    assert table_lines(out.getvalue(), "beta")[0].endswith("0 m (n=2)")
    assert "in % except Left_over & # (own units)" in out.getvalue()
    t1 = pd.read_csv(tmp_path / "table1_overall.csv").set_index("model")
    assert t1.loc["alpha", "Left_over & #"] == pytest.approx(0.25)  # as measured, not x100
    tex = (tmp_path / "table1_overall.tex").read_text()
    # escaped by tabulate; one base task: no interval for a measure without a range
    assert r"Left\_over \& \#" in tex and r"0.25 m\,{\scriptsize [n/a] (n=2)}" in tex
    assert "Left_over & #" not in tex


def test_a_registry_without_the_builtins_reports_without_them(tmp_path):
    plugins = Plugins(entry_points=False, extra=[PathRatio()])
    out = io.StringIO()
    frames = report_records(records(), plugins, out_dir=tmp_path, stream=out)
    t1 = pd.read_csv(tmp_path / "table1_overall.csv")
    assert [c for c in t1.columns if not c.endswith(("_k", "_n", "_lo", "_hi", "_clusters"))] == [
        "model",
        "prompt",
        "tasks",
        "PCSR",
        "RGSR",
        "dSR",
        "Path ratio",
    ]
    t3 = pd.read_csv(tmp_path / "table3_qualified_failures.csv")
    kept = [c for c in t3.columns if not c.endswith(("_k", "_n", "_lo", "_hi", "_clusters"))]
    assert kept == ["model", "prompt", "tasks", "FR", "Path ratio"]
    assert not {"tar", "ts", "early20_ts", "ams"} & set(frames["pairs"].columns)
    for label in ("TAR", "TS", "AMS"):
        assert f" {label} " not in out.getvalue()
    assert (tmp_path / "fig_prompt_differences.png").exists() and not (tmp_path / "fig_qf_distributions.png").exists()
    with pytest.raises(UserError, match="^unknown metric 'tar'; valid choices: path_ratio$"):
        report_records(records(), plugins, metrics=["tar"], stream=io.StringIO())


def test_figures_scale_a_metric_as_registered(tmp_path):
    from conflictbench.metrics import evaluate_pairs, prompt_couples, prompt_differences, with_model
    from conflictbench.report import figures

    plugins = Plugins(entry_points=False, extra=[Plain()])
    spec = plugins.metrics()["steps_left"]
    p1 = [EpisodeRecord(**{**r.__dict__, "prompt": "p1", "episode_id": r.episode_id + "-p1"}) for r in records()]
    episodes = records() + p1
    refs = {(r.policy, r.prompt): r for r in episodes if r.case_id is None}
    cons = [r for r in episodes if r.case_id is not None]
    frame = with_model(evaluate_pairs([refs[(c.policy, c.prompt)] for c in cons], cons, plugins=plugins))
    differences = prompt_differences(prompt_couples(frame, ["steps_left"]), ["steps_left"])
    assert list(differences["steps_left"]) == [0.0, 0.0]
    for path in (
        figures.qualified_failure_distributions(frame, tmp_path / "qf.png", [spec]),
        figures.prompt_difference_figure(differences, tmp_path / "diff.png", [spec]),
    ):
        assert path.read_bytes().startswith(b"\x89PNG") and path.stat().st_size > 5_000
