"""``conflictbench compare``: paired differences between two sides of real Parquet stores, with verdicts."""

from __future__ import annotations

import io
from dataclasses import replace

import pandas as pd
import pytest
from test_report import episode, two_models
from testing_support import in_tasks

import conflictbench
from conflictbench.cli.compare import command
from conflictbench.core import UserError
from conflictbench.store import EpisodeStore


@pytest.fixture
def plugins():
    return conflictbench.plugins(entry_points=False)


def store_of(path, records):
    store = EpisodeStore(path)
    for record in records:
        store.write(record)
    return path


def p1(records):
    """The same episodes under P1 (each its own)."""
    return [replace(r, prompt="p1", episode_id=f"{r.episode_id}-p1") for r in records]


def test_two_models_of_one_store_differ_where_their_pairs_do(tmp_path, plugins, capsys):
    # in each of 10 base tasks: both references succeed; alpha completes c2 under the conflict, beta nothing
    extra = episode("alpha", "c3", 0.3, 0.1, False, "physical", "L3")  # a case beta never played
    root = store_of(tmp_path / "run", in_tasks(two_models(), 10) + [extra])
    assert command([str(root), "alpha", "beta", "--csv", str(tmp_path / "c.csv")], plugins) == 0
    text = capsys.readouterr().out
    assert "A = alpha, B = beta" in text
    assert "20 matched pairs, matched on LIBERO suite, task, case, suite version, initial state, prompt, seed" in text
    assert "1 pair of alpha without a counterpart (1 case not played by the other side)" in text
    assert "every pair of beta has its counterpart" in text
    rows = pd.read_csv(tmp_path / "c.csv").set_index(["scope", "group"])
    overall = rows.loc[("overall", "all")]
    # RGSR: alpha 10/20, beta 0/20 -> +50 points, in all 10 base tasks alike
    assert (overall["RGSR_a"], overall["RGSR_b"], overall["RGSR"]) == (0.5, 0.0, 0.5)
    assert overall["RGSR_clusters"] == 10 and overall["RGSR_lo"] > 0 and overall["RGSR_verdict"] == "A higher"
    assert overall["PCSR"] == 0 and overall["PCSR_verdict"] == "no detectable difference"
    assert overall["ams_verdict"] == "B higher"  # beta stood still: AMS 100 against alpha's 25
    family = rows.loc["family"]
    assert list(family.index) == ["grounding", "spatial"]  # the paper's order, the families played
    # spatial: alpha always completes c2, beta never; grounding: neither completes c1
    assert family.loc["spatial", "RGSR_verdict"] == "A higher"
    assert family.loc["grounding", "RGSR_verdict"] == "no detectable difference"
    assert (family["RGSR_p_adjusted"] >= family["RGSR_p"]).all()  # Holm among the family rows
    assert "overall tested at 5 %, family rows and level rows each Holm-corrected among themselves" in text


def test_p0_against_p1_of_one_model(tmp_path, plugins, capsys):
    p0 = in_tasks(two_models(), 8)
    changed = [replace(r, success=False) if r.case_id == "c2" and r.policy == "alpha" else r for r in p1(p0)]
    root = store_of(tmp_path / "run", p0 + changed)
    assert command([str(root), "alpha@p0", "alpha@p1"], plugins) == 0
    text = capsys.readouterr().out
    assert "16 matched pairs, matched on LIBERO suite, task, case, suite version, initial state, seed" in text
    rgsr = text.split("== RGSR: A - B")[1].split("\n\n")[0]
    assert "p0 vs p1  all" in rgsr and "+50.0 [" in rgsr and "A higher" in rgsr


def test_the_same_model_in_two_stores(tmp_path, plugins, capsys):
    first = store_of(tmp_path / "one", in_tasks(two_models(), 6))
    second = store_of(tmp_path / "two", in_tasks(two_models(), 6))
    assert command([str(first), "beta", "beta", "--against", str(second)], plugins) == 0
    text = capsys.readouterr().out
    assert "12 matched pairs" in text and "A higher" not in text and "B higher" not in text


@pytest.mark.parametrize(
    ("sides", "message"),
    [
        (["alpha", "gamma"], r"no model 'gamma' in .*: it has alpha, beta"),
        (["alpha", "alpa"], r"did you mean 'alpha'\?"),
        (["alpha", "alpha"], "A and B are both alpha"),
        (["alpha@p2", "beta"], "the prompt condition after @ must be one of p0, p1"),
        (["alpha@p1", "beta"], "holds no p1 pairs of alpha"),
    ],
)
def test_a_side_that_is_not_there_is_one_line(tmp_path, plugins, sides, message):
    root = store_of(tmp_path / "run", two_models())
    with pytest.raises(UserError, match=message):
        command([str(root), *sides], plugins)


def test_the_command_line_names_its_mistakes_in_one_line(tmp_path):
    import subprocess
    import sys

    root = store_of(tmp_path / "run", two_models())
    done = subprocess.run([sys.executable, "-m", "conflictbench.cli", "compare", str(root), "alpha", "nobody"],
                          capture_output=True, text=True)  # fmt: skip
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.strip().count("\n") == 0 and "no model 'nobody'" in done.stderr


def test_a_pair_stored_twice_counts_once_and_keys_match_across_dtypes():
    from conflictbench.metrics.paired import EXPERIMENT_KEYS, match

    def side(rows, steps):
        return pd.DataFrame(
            {"suite": "s", "task_id": [r[0] for r in rows], "case_id": [r[1] for r in rows], "conflict_suite": None,
             "init_state": 0, "prompt": "p0", "seed": 7, "max_steps": steps, "family": "spatial", "level": "L1",
             "reference_success": True, "conflict_success": [r[2] for r in rows],
             "conflict_episode": [f"e{i}" for i in range(len(rows))]}
        )  # fmt: skip

    a = side([(0, "c0", True), (1, "c1", False), (1, "c1", True), (2, "c2", False)], 300)  # c1 stored twice
    b = side([(0, "c0", False), (1, "c1", False), (3, "c3", True)], 300.0)  # max_steps read back as a float
    found = match(a, b, EXPERIMENT_KEYS, [])
    assert len(found.frame) == 2  # c0 and c1: 300 and 300.0 are one step budget
    assert found.frame["conflict_success_a"].tolist() == [True, False]  # c1's first, by its conflict episode
    assert found.unmatched_a == {"stored more than once (counted once)": 1, "case not played": 1}
    assert found.unmatched_b == {"case not played": 1}


def test_the_best_value_is_not_marked_where_the_pairs_both_played_say_it_is_worse(tmp_path, plugins):
    from conflictbench.report import report_records

    # alpha completes the original goal under the conflict in 10 of 40 tasks (RGSR 25 %, the lowest, so the
    # "best"); beta plays only those 10 tasks and completes it in 5 (50 %): on the pairs both played alpha is worse
    records = []
    for task in range(40):
        records += [replace(episode("alpha", None, 0.1, 0.2, True), task_id=task, episode_id=f"a-r-{task}"),
                    replace(episode("alpha", "c1", 0.1, 0.2, task < 10, "spatial", "L1"), task_id=task,
                            episode_id=f"a-c-{task}")]  # fmt: skip
    for task in range(10):
        records += [replace(episode("beta", None, 0.1, 0.2, True), task_id=task, episode_id=f"b-r-{task}"),
                    replace(episode("beta", "c1", 0.1, 0.2, task < 5, "spatial", "L1"), task_id=task,
                            episode_id=f"b-c-{task}")]  # fmt: skip
    out = io.StringIO()
    report_records(records, plugins, stream=out, figures=False)
    table1 = out.getvalue().split("== Table 2")[0]
    alpha = next(line for line in table1.splitlines() if line.startswith("alpha"))
    assert "25.0 (10/40)" in alpha and "25.0 (10/40)*" not in alpha
    assert "not marked: RGSR" in table1
