"""Damage inside a data page (#42, section 5): a file whose key columns read but whose arrays do not. The reports,
the viewer and compare choose episodes by their keys and meet the damage only when they load the arrays: the read
that meets it sets the file aside, says so in one line, and goes on in the same call without it."""

from __future__ import annotations

import io

import pandas as pd
import pyarrow.parquet as pq
from test_store_damage import set_aside, stored_pairs

from conflictbench.store import EpisodeStore


def damage_the_actions_page(path) -> None:
    """Garbage over the header of the ``actions`` column's first page: the footer and every key column intact."""
    meta = pq.read_metadata(path).row_group(0)
    [actions] = [meta.column(i) for i in range(meta.num_columns) if meta.column(i).path_in_schema.startswith("actions")]
    start = actions.dictionary_page_offset if actions.has_dictionary_page else actions.data_page_offset
    data = bytearray(path.read_bytes())
    data[start : start + 24] = b"\xff" * 24
    path.write_bytes(bytes(data))


def lines_naming(err: str, eid: str) -> list[str]:
    return [x for x in err.splitlines() if f"{eid}.parquet" in x]


def test_a_report_meeting_a_damaged_array_goes_on_without_it_in_the_same_call(tmp_path, plugins, capsys):
    from conflictbench.report import report_store

    store = stored_pairs(tmp_path / "store")
    damage_the_actions_page(store.path_for("noop", "con1"))
    assert store.read_table(columns=["episode_id"]).num_rows == 5  # its keys read
    first = report_store(store, plugins, stream=io.StringIO(), figures=False)  # today: UserError "run it again"
    [line] = lines_naming(capsys.readouterr().err, "con1")
    assert "damaged" in line and "set aside as damaged/episodes/noop/con1.parquet" in line
    assert set_aside(store, "noop", "con1").is_file() and store.stored_ids() == {"ref0", "ref1", "ref2", "con0"}
    again = report_store(EpisodeStore(store.root), plugins, stream=io.StringIO(), figures=False)
    assert first.keys() == again.keys()
    for name, frame in first.items():  # what the next call, which never sees the file, reports
        pd.testing.assert_frame_equal(frame, again[name])
    assert lines_naming(capsys.readouterr().err, "con1") == []


def test_the_viewer_meeting_a_damaged_array_goes_on_without_it_in_the_same_call(tmp_path, plugins, capsys):
    from conflictbench.view import Selection, build_site

    store = stored_pairs(tmp_path / "store")
    damage_the_actions_page(store.path_for("noop", "ref0"))
    built = build_site(store.root, tmp_path / "site", plugins, Selection(), videos=0, progress=False)
    assert built.pairs == 1  # con0's reference is gone: its pair with it
    assert len(lines_naming(capsys.readouterr().err, "ref0")) == 1
    assert set_aside(store, "noop", "ref0").is_file()


def test_compare_meeting_a_damaged_array_goes_on_without_it(tmp_path, plugins, capsys):
    from conflictbench.report.from_store import store_frame
    from conflictbench.report.summary import select_metrics

    store = stored_pairs(tmp_path / "store")
    damage_the_actions_page(store.path_for("noop", "con0"))
    frame, models = store_frame(store, plugins, select_metrics(plugins, None))
    assert len(frame) == 1 and len(models) == 1
    assert len(lines_naming(capsys.readouterr().err, "con0")) == 1


def test_a_damaged_array_that_cannot_be_set_aside_is_left_out_and_the_report_goes_on(tmp_path, plugins, capsys):
    """Where the file cannot be moved (here a file where the quarantine folder would go), the store leaves it out
    of its later readings, so the report, choosing again, does not meet it twice."""
    from conflictbench.report import report_store

    store = stored_pairs(tmp_path / "store")
    damage_the_actions_page(store.path_for("noop", "con1"))
    (store.root / "damaged").write_text("in the way")
    report_store(store, plugins, stream=io.StringIO(), figures=False)
    [line] = lines_naming(capsys.readouterr().err, "con1")
    assert "cannot set it aside" in line
    assert store.path_for("noop", "con1").exists() and "con1" not in store.stored_ids()
