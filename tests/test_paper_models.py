"""The paper's model names are the paper's data (conflictbench/report/paper_data), not the plugin contract's: a
published entry's ``paper_model`` is checked against them where the paper is read, in one line."""

from __future__ import annotations

import pytest

import conflictbench
from conflictbench import hookimpl
from conflictbench.core import PluginError, Plugins
from conflictbench.report.paper import declared_paper_models, paper_models


def published(paper_model):
    class Checkpoint:
        @hookimpl
        def conflictbench_register_published_results(self, register):
            register("official-x", policy="noop", checkpoint="(built in)", success={"libero_goal": 50.0},
                     protocol={"episodes_per_suite": 500}, source="test", url="https://example.org/t",
                     date="2026-01-01", paper_model=paper_model)  # fmt: skip

    return Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[Checkpoint()])


def test_the_papers_models_are_the_rows_of_its_first_table():
    assert paper_models() == ("OpenVLA", "OpenVLA-OFT", "pi0", "pi0-FAST", "pi0.5", "GR00T N1.7", "VLA-JEPA", "UniVLA")


def test_a_paper_model_the_paper_lacks_is_one_line_where_it_is_declared_and_where_the_report_reads_it():
    from conflictbench.cli.published import take_declaration

    plugins = published("pi 0.5")  # registering it is fine: the contract knows nothing of the paper
    expected = r"^published result 'official-x' of .*: paper_model must be one of OpenVLA, .*, got 'pi 0.5'$"
    with pytest.raises(PluginError, match=expected):
        take_declaration(["model=noop", "model.published=official-x"], plugins)
    with pytest.raises(PluginError, match=expected):
        declared_paper_models({("noop", "abc"): "official-x"}, plugins.published_results())


def test_a_paper_model_of_the_paper_is_declared_and_read():
    from conflictbench.cli.published import take_declaration

    plugins = published("pi0.5")
    assert take_declaration(["model=noop", "model.published=official-x"], plugins) == (["model=noop"], "official-x")
    assert declared_paper_models({("noop", "abc"): "official-x"}, plugins.published_results()) == {
        ("noop", "abc"): "pi0.5"
    }


def test_a_paper_model_that_is_not_a_name_is_refused_when_registered():
    with pytest.raises(PluginError, match=r"paper_model must be a model's name \(the paper's\) or None, got 3$"):
        published(3).published_results()
