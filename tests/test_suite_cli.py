"""``conflictbench suite ...``: exit codes, files, and the shipped data's integrity checks."""

from __future__ import annotations

import json
from collections import Counter

import pytest

from conflictbench.cli import main
from conflictbench.core import FAMILIES, LEVELS, LIBERO_SUITES
from conflictbench.tasks.suite.file import load_suite, shipped_suite_path


def run(capsys, *argv):
    code = main(["suite", *argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.sim  # LIBERO's base tasks
def test_validate_the_shipped_suite(capsys):
    code, out, err = run(capsys, "validate")
    assert code == 0, out
    assert "all valid" in err and out == ""


@pytest.mark.sim  # LIBERO's base tasks
def test_export_then_validate_the_export(tmp_path, capsys):
    path = tmp_path / "all.jsonl"
    code, _, _ = run(capsys, "export", str(path))
    assert code == 0
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert len(rows) == len(load_suite().cases)
    for key in (
        "case_id",
        "suite",
        "task_id",
        "base_instruction",
        "instruction",
        "family",
        "level",
        "witness",
        "status",
    ):
        assert key in rows[0]
    small = tmp_path / "some.jsonl"
    small.write_text("\n".join(json.dumps(r) for r in rows[::25]) + "\n")
    code, out, err = run(capsys, "validate", str(small))
    assert code == 0, out


@pytest.mark.sim  # LIBERO's base tasks
def test_validate_reports_each_failing_case_and_exits_1(tmp_path, capsys):
    rows = [json.loads(line) for line in shipped_suite_path().read_text().splitlines()[1:4]]
    rows[1]["instruction"] = rows[1]["base_instruction"]
    path = tmp_path / "bad.jsonl"
    path.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    code, out, err = run(capsys, "validate", str(path))
    assert code == 1
    assert f"{rows[1]['case_id']}: the instruction equals the base instruction" in out
    assert rows[0]["case_id"] not in out and "1 invalid" in err


def test_an_empty_suite_file_is_refused(tmp_path, capsys):
    empty = tmp_path / "empty.jsonl"
    empty.write_text("")
    code, _, err = run(capsys, "validate", str(empty))
    assert code == 2 and "holds no cases" in err


@pytest.mark.parametrize(
    "mutate,message",
    [
        (lambda lines: lines[:2] + ["{not json"] + lines[3:], "line 3: not valid JSON"),
        (lambda lines: [lines[0], lines[1].replace('"level": "L', '"level": "M')] + lines[2:], "line 2, field 'level'"),
        (lambda lines: [lines[0], lines[1].replace('"task_id": ', '"task_id": "')] + lines[2:], "line 2"),
        (lambda lines: [lines[0], lines[2], lines[1]] + lines[3:], "line 1, field 'sha256': checksum mismatch"),
        (
            lambda lines: [lines[0].replace('"format_version": 1', '"format_version": 9')] + lines[1:],
            "field 'format_version'",
        ),
    ],
)
def test_a_malformed_or_tampered_file_is_one_line_and_exit_2(tmp_path, capsys, mutate, message):
    lines = shipped_suite_path().read_text().splitlines()
    path = tmp_path / "suite.jsonl"
    path.write_text("\n".join(mutate(lines)) + "\n")
    code, out, err = run(capsys, "validate", str(path))
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1


def test_stats_counts_every_cell(capsys):
    code, out, _ = run(capsys, "stats")
    assert code == 0
    suite = load_suite()
    counts = Counter((c.family, c.level, c.suite) for c in suite.accepted())
    row = next(line for line in out.splitlines() if line.startswith("spatial") and " L3 " in f" {line} ")
    assert row.split()[2:6] == [str(counts[("spatial", "L3", s)]) for s in LIBERO_SUITES]
    assert "base tasks used: 40" in out
    code, md, _ = run(capsys, "stats", "--markdown")
    table = [line for line in md.splitlines() if line.startswith("|")]
    assert (
        table[0].startswith("| family | level | libero_spatial") and len(table) == 2 + len(FAMILIES) * len(LEVELS) + 1
    )


def test_sample_is_stratified(tmp_path, capsys):
    out_file = tmp_path / "review.jsonl"
    code, _, err = run(capsys, "sample", "--per-cell", "4", "--out", str(out_file))
    assert code == 0
    rows = [json.loads(line) for line in out_file.read_text().splitlines()]
    cells = Counter((r["family"], r["level"]) for r in rows)
    assert set(cells.values()) == {4} and len(cells) == 16
    for family in FAMILIES:
        suites = {r["suite"] for r in rows if r["family"] == family}
        assert len(suites) >= 3
    assert rows[0]["decision"] == "" and "note" in rows[0]


def test_export_with_prompts_gives_both_conditions(tmp_path, capsys):
    path = tmp_path / "p.jsonl"
    assert run(capsys, "export", str(path), "--prompts")[0] == 0
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    first = [r for r in rows if r["case_id"] == rows[0]["case_id"]]
    assert [r["prompt"] for r in first] == ["p0", "p1"]
    assert first[0]["prompt_text"] == first[0]["instruction"] != first[1]["prompt_text"]


@pytest.mark.parametrize(
    "argv,message",
    [
        (["sample"], "the following arguments are required: --per-cell"),
        (["sample", "--per-cell", "0"], "--per-cell must be at least 1"),
        (["frobnicate"], "unknown suite command 'frobnicate'"),
        ([], "name a command: validate, stats, sample, export, build"),
        (["validate", "/no/such/file.jsonl"], "suite file not found"),
        (["stats", "--colour"], "unrecognized arguments: --colour"),
    ],
)
def test_usage_mistakes_exit_2(capsys, argv, message):
    code, out, err = run(capsys, *argv)
    assert code == 2 and message in err


@pytest.mark.e2e
@pytest.mark.sim  # LIBERO's base tasks
def test_build_is_deterministic_and_matches_the_shipped_file(capsys):
    code, _, err = run(capsys, "build", "--check")
    assert code == 0, err
    assert "identical to a fresh build" in err


@pytest.mark.e2e
@pytest.mark.sim  # LIBERO's base tasks
def test_build_with_another_seed_differs(tmp_path, capsys):
    out = tmp_path / "s1.jsonl"
    assert run(capsys, "build", "--seed", "1", "--out", str(out))[0] == 0
    other = load_suite(out)
    assert other.version == load_suite().version
    assert {c.case_id for c in other.cases} != {c.case_id for c in load_suite().cases}
    assert json.loads(out.read_text().splitlines()[0])["seed"] == 1
    assert {c.status for c in other.cases} == {"pending"} and other.accepted() == []  # nobody has read them


@pytest.mark.sim  # LIBERO's base tasks
def test_review_mistakes_are_one_line_and_exit_2(tmp_path, capsys):
    unknown = tmp_path / "v.jsonl"
    unknown.write_text(json.dumps({"case_id": "nope-ins-L1-00000000", "verdict": "valid", "note": "x"}) + "\n")
    target = tmp_path / "review.jsonl"
    code, _, err = run(capsys, "review-merge", str(unknown), "--reviewer", "r", "--reviews", str(target))
    assert code == 2 and "name cases the suite does not have" in err and not target.exists()
    code, _, err = run(capsys, "review-merge", str(tmp_path / "missing.jsonl"), "--reviewer", "r")
    assert code == 2 and "cannot read" in err
    code, _, err = run(capsys, "validate", str(tmp_path))  # a directory
    assert code == 2 and "cannot read the suite file" in err


@pytest.mark.sim  # LIBERO's base tasks (the sheets carry each scene's facts)
def test_review_sheets_then_merge_the_verdicts(tmp_path, capsys):
    cases = [c for c in load_suite().accepted() if (c.suite, c.task_id) == ("libero_goal", 8)][:3]
    source = tmp_path / "cases.jsonl"
    source.write_text("".join(json.dumps(c.to_dict()) + "\n" for c in cases))
    code, _, err = run(
        capsys, "review-sheets", "--suite", str(source), "--out", str(tmp_path / "sheets"), "--size", "2"
    )
    assert code == 0 and "wrote 3 cases in 2 batch(es)" in err
    sheets = sorted((tmp_path / "sheets").glob("batch-*.md"))
    text = "\n".join(p.read_text() for p in sheets)
    assert len(sheets) == 2 and text.count("### Scene: libero_goal task 8") == 2  # each sheet is self-contained
    assert text.count("# Reviewing conflict cases") == 2 and all(c.case_id in text for c in cases)
    assert "- the bowl [akita_black_bowl_1; akita_black_bowl; object" in text and "Positions in initial state 0" in text

    verdicts = tmp_path / "verdicts.jsonl"
    verdicts.write_text(
        json.dumps({"case_id": cases[0].case_id, "verdict": "valid", "note": "fine"})
        + "\n"
        + json.dumps({"case_id": cases[1].case_id, "verdict": "questionable", "note": "two readings"})
        + "\n"
    )
    reviews = tmp_path / "review.jsonl"
    code, _, err = run(capsys, "review-merge", str(verdicts), "--reviewer", "reader-1", "--reviews", str(reviews))
    assert code == 0 and "appended 2 decision(s)" in err
    rows = [json.loads(line) for line in reviews.read_text().splitlines()]
    assert [(r["decision"], r["reviewer"], r["round"]) for r in rows] == [
        ("accepted", "reader-1", 1),
        ("removed", "reader-1", 1),
    ]
    assert rows[1]["note"] == "questionable: two readings"
    # A recheck needs another reader; the same reader is refused with one line and exit 2.
    again = ["review-merge", str(verdicts), "--reviews", str(reviews), "--round", "2"]
    code, _, err = run(capsys, *again, "--reviewer", "reader-1")
    assert code == 2 and "needs another reader" in err
    code, _, err = run(capsys, *again, "--reviewer", "reader-2")
    assert code == 0 and len(reviews.read_text().splitlines()) == 4
    # A round-2 recheck names the cases round 1 removed: --only includes removed ones.
    source.write_text("".join(json.dumps({**c.to_dict(), "status": "removed"}) + "\n" for c in cases))
    (tmp_path / "ids.txt").write_text(cases[1].case_id + "\n")
    only = ["review-sheets", "--suite", str(source), "--only", str(tmp_path / "ids.txt"), "--out", str(tmp_path / "r2")]
    code, _, err = run(capsys, *only)
    assert code == 0 and "wrote 1 cases in 1 batch(es)" in err
    assert cases[1].case_id in (tmp_path / "r2" / "batch-001.md").read_text()
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps({"case_id": cases[0].case_id, "verdict": "fine"}) + "\n")
    code, _, err = run(capsys, "review-merge", str(bad), "--reviewer", "reader-3", "--reviews", str(reviews))
    assert code == 2 and "a verdict needs case_id, verdict" in err
