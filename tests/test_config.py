"""Composing the Hydra config tree: every group, every option, and the checks on run options."""

from __future__ import annotations

from importlib import resources

import pytest
from hydra import compose, initialize_config_module
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from conflictbench.cli.run import group_choices, register_model_configs, run_options
from conflictbench.core import FAMILIES, LEVELS, UserError


@pytest.fixture
def composed(plugins):
    register_model_configs(plugins)
    GlobalHydra.instance().clear()
    with initialize_config_module(config_module="conflictbench.conf", version_base=None):
        yield lambda *overrides: compose("config", overrides=list(overrides))
    GlobalHydra.instance().clear()


def test_default_composition_is_the_quick_slice(composed):
    cfg = composed()
    opts = run_options(cfg.run)
    assert list(cfg.suite.families) == list(FAMILIES)
    assert list(cfg.level.levels) == list(LEVELS)
    assert list(cfg.prompt.conditions) == ["p0"]
    assert opts.init_states == [0] and opts.cases_per_cell == 1 and opts.workers == 2
    assert (opts.backend, opts.ray_address) == ("local", None)
    assert str(opts.out) == "results"
    assert cfg.model.weights is None and cfg.model.sample_gripper  # the learned subject's settings: the default model


@pytest.mark.parametrize("group", ["suite", "level", "prompt", "run"])
def test_every_option_of_every_group_composes(composed, plugins, group):
    options = group_choices(group, plugins)
    assert len(options) >= 2
    for option in options:
        cfg = composed(f"{group}={option}")
        assert cfg[group] is not None
        if group == "run":
            run_options(cfg.run)


def test_family_and_level_options_select_one_each(composed):
    for family in FAMILIES:
        assert list(composed(f"suite={family}").suite.families) == [family]
    for level in LEVELS:
        assert list(composed(f"level={level}").level.levels) == [level]
    assert list(composed("prompt=both").prompt.conditions) == ["p0", "p1"]


def test_paper_preset_is_the_papers_protocol(composed):
    opts = run_options(composed("run=paper").run)
    assert opts.init_states == [0, 1, 2, 3, 4] and opts.cases_per_cell is None


def test_models_are_the_registered_policies_with_their_config_fields(composed, plugins):
    assert group_choices("model", plugins) == sorted(plugins.policies())
    cfg = composed("model=random", "model.seed=11")
    assert OmegaConf.to_container(cfg.model) == {"seed": 11, "scale": 1.0}
    spec = plugins.policy("random")
    assert spec.make_config(OmegaConf.to_container(cfg.model)).seed == 11
    with pytest.raises(Exception, match="seed"):
        composed("model=random", "model.seed=not-a-number")
    assert OmegaConf.to_container(composed("model=noop").model) == {}


def test_run_options_accept_a_list_of_initial_states(composed):
    opts = run_options(composed("run.init_states=[4,0,4]", "run.cases_per_cell=all").run)
    assert opts.init_states == [0, 4] and opts.cases_per_cell is None


def test_run_options_name_base_tasks_and_cases(composed):
    opts = run_options(composed("run.tasks=[libero_goal/3,libero_10/0,libero_goal/3]", "run.cases=[a-1]").run)
    assert opts.tasks == [("libero_10", 0), ("libero_goal", 3)] and opts.cases == ["a-1"]
    opts = run_options(composed().run)
    assert opts.tasks is None and opts.cases is None


@pytest.mark.parametrize(
    "override, message",
    [
        ("run.init_states=0", "run.init_states must be an integer >= 1"),
        ("run.init_states=51", "50 fixed initial states"),
        ("run.init_states=[3,50]", "0..49"),
        ("run.cases_per_cell=-1", "run.cases_per_cell"),
        ("run.cases_per_cell=some", "run.cases_per_cell"),
        ("run.workers=0", "run.workers must be an integer >= 1"),
        ("run.backend=dask", "unknown run.backend 'dask'; valid choices: local, ray"),
        ("run.libero_suites=[libero_90]", "unknown LIBERO suite 'libero_90'"),
        ("run.tasks=[libero_gaol/3]", "'libero_gaol/3' names no LIBERO suite \\(did you mean libero_goal\\?\\)"),
        ("run.tasks=[libero_goal/10]", "task ids 0-9\\), got 'libero_goal/10'"),
        ("run.tasks=[libero_goal]", "got 'libero_goal'"),
        ("run.cases=[]", "run.cases must name at least one, or be null"),
        ("run.max_steps=0", "run.max_steps \\(or null\\) must be an integer >= 1, got 0"),
        ("run.max_steps=ten", "run.max_steps"),
    ],
)
def test_bad_run_options_are_user_errors(composed, override, message):
    with pytest.raises(UserError, match=message):
        run_options(composed(override).run)


def test_config_files_are_package_data():
    names = {p.name for p in resources.files("conflictbench.conf").iterdir()}
    assert "config.yaml" in names
    for group in ("suite", "level", "prompt", "run"):
        assert any(p.name.endswith(".yaml") for p in (resources.files("conflictbench.conf") / group).iterdir())
