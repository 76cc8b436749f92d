"""Core 2: hooks called through pluggy, per-policy protocol, unknown hooks refused, attribution."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import ActionContext, PluginError, Plugins, PolicyError


def make(*extra) -> Plugins:
    return Plugins(BUILTIN_PLUGINS, entry_points=False, extra=extra)


def context(policy: str) -> ActionContext:
    return ActionContext(
        policy=policy, suite="libero_goal", task_id=0, prompt="p0", case_id=None, step=0, chunk_index=0
    )


class Named:
    """A plugin object with a readable name (the plugin manager names extras by ``__name__``)."""

    def __init__(self, name: str):
        self.__name__ = name


# -- per-policy protocol ------------------------------------------------------------------------
class Model(Named):
    """Registers two policies with their own prompt template and post-processing, as a VLA plugin would."""

    @hookimpl
    def conflictbench_register_policies(self, register):
        register(
            "model-a",
            load=lambda cfg: None,
            format_prompt=lambda text, condition: f"In: {text.lower()}? ({condition})",
            postprocess=lambda action, ctx: np.concatenate([action[:6], [-action[6]]]),
        )
        register("model-b", load=lambda cfg: None)


def test_a_policys_own_prompt_and_postprocessing_apply_to_that_policy_only():
    plugins = make(Model("model"))
    assert plugins.format_prompt("Open It", "p0", "model-a") == "In: open it? (p0)"
    assert plugins.format_prompt("Open It", "p0", "model-b") == "Open It"
    assert plugins.format_prompt("Open It", "p0", "noop") == "Open It"
    action = np.array([0.1, 0, 0, 0, 0, 0, 1.0])
    np.testing.assert_array_equal(plugins.postprocess_action(action, context("model-a"))[6], -1.0)
    np.testing.assert_array_equal(plugins.postprocess_action(action, context("model-b")), action)
    np.testing.assert_array_equal(plugins.postprocess_action(action, context("noop")), action)


def test_global_hooks_run_after_the_policys_own_in_the_documented_order():
    seen = []

    class Lab(Named):
        @hookimpl
        def conflictbench_format_prompt(self, instruction, condition, policy):
            return f"[lab] {instruction}" if condition == "p1" else None

        @hookimpl
        def conflictbench_postprocess_action(self, action, context):
            seen.append(action.copy())
            return np.clip(action, -0.5, 0.5)

    plugins = make(Model("model"), Lab("lab"))
    # A deliberate cross-cutting prompt style overrides the model's template; where it declines, the model's applies.
    assert plugins.format_prompt("x", "p1", "model-a") == "[lab] x"
    assert plugins.format_prompt("X", "p0", "model-a") == "In: x? (p0)"
    out = plugins.postprocess_action(np.array([0.9, 0, 0, 0, 0, 0, 1.0]), context("model-a"))
    assert seen[-1][6] == -1.0  # the global chain received the policy's own output
    np.testing.assert_array_equal(out, [0.5, 0, 0, 0, 0, 0, -0.5])


def test_a_policys_own_postprocess_with_a_wrong_shape_is_a_policy_error():
    class Bad(Named):
        @hookimpl
        def conflictbench_register_policies(self, register):
            register("bad", load=lambda cfg: None, postprocess=lambda action, ctx: action[:2])

    with pytest.raises(PolicyError, match=r"postprocess of policy 'bad' returned shape \(2,\)"):
        make(Bad("bad")).postprocess_action(np.zeros(7), context("bad"))


def test_registration_checks_the_protocol_callables():
    class Bad(Named):
        @hookimpl
        def conflictbench_register_policies(self, register):
            register("bad", load=lambda cfg: None, format_prompt="In: {instruction}")

    with pytest.raises(PluginError, match="format_prompt must be callable"):
        make(Bad("bad")).policies()


# -- through pluggy ------------------------------------------------------------------------------
def test_wrapper_implementations_wrap_the_post_processing_chain():
    class Scale(Named):
        @hookimpl
        def conflictbench_postprocess_action(self, action, context):
            return action * 4

    class ClipAll(Named):
        @hookimpl(wrapper=True)
        def conflictbench_postprocess_action(self, action, context):
            results = yield
            return [np.clip(r, -1, 1) for r in results]

    out = make(Scale("scale"), ClipAll("clip")).postprocess_action(np.full(7, 0.5), context("noop"))
    np.testing.assert_array_equal(out, np.ones(7))


def test_wrappers_see_register_hooks_and_tracing_records_them():
    wrapped = []

    class Watch(Named):
        @hookimpl(wrapper=True)
        def conflictbench_register_metrics(self, register):
            wrapped.append("before")
            result = yield
            wrapped.append("after")
            return result

    plugins = make(Watch("watch"))
    lines: list[str] = []
    plugins.pm.trace.root.setwriter(lines.append)
    undo = plugins.pm.enable_tracing()
    try:
        metrics = plugins.metrics()
    finally:
        undo()
    assert "tar" in metrics and wrapped == ["before", "after"]
    assert any("conflictbench_register_metrics" in line for line in lines)


def test_register_knows_its_caller_even_through_a_helper():
    def register_all(register, names):  # a plugin's own helper, not the hook implementation
        for name in names:
            register(name, compute=lambda pair: 0.0, higher_is_better=True)

    class One(Named):
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register_all(register, ["one_a", "one_b"])

    class Two(Named):
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("two", compute=lambda pair: 1.0)

    plugins = Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[One("one"), Two("two")])
    plugins._sources["one"] = plugins.source("one").__class__("pkg-one", "1.0")
    plugins._sources["two"] = plugins.source("two").__class__("pkg-two", "2.0")
    metrics = plugins.metrics()
    assert {m: metrics[m].plugin for m in ("one_a", "one_b", "two", "tar")} == {
        "one_a": "pkg-one",
        "one_b": "pkg-one",
        "two": "pkg-two",
        "tar": "conflictbench",
    }
    assert metrics["one_a"].direction == "higher" and metrics["two"].direction is None


# -- unknown hooks -------------------------------------------------------------------------------
def test_a_misspelled_hook_is_an_error_naming_the_plugin_and_the_hook():
    class Typo(Named):
        @hookimpl
        def conflictbench_register_policy(self, register):
            register("never", load=lambda cfg: None)

    with pytest.raises(
        PluginError,
        match=r"plugin typo .*unknown hook 'conflictbench_register_policy' "
        r"\(did you mean conflictbench_register_policies\?\)",
    ):
        make(Typo("typo"))


def test_a_hook_argument_the_spec_lacks_is_an_error_naming_the_plugin():
    class Extra(Named):
        @hookimpl
        def conflictbench_postprocess_action(self, action, context, observation):
            return None

    with pytest.raises(PluginError, match=r"plugin extra .*observation"):
        make(Extra("extra"))


# -- the previous contract still works -----------------------------------------------------------
@dataclass
class LegacyConfig:
    gain: float = 1.0


def test_the_previous_contract_still_registers_and_runs():
    class Legacy(Named):
        @hookimpl
        def conflictbench_register_policies(self, register):
            register("legacy", load=lambda cfg: cfg, config=LegacyConfig)

        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("legacy_metric", compute=lambda pair: 0.5, description="old style")

        @hookimpl
        def conflictbench_format_prompt(self, instruction, condition, policy):
            return None if policy != "legacy" else f"<{instruction}>"

        @hookimpl
        def conflictbench_postprocess_action(self, action, context):
            return None if context.policy != "legacy" else action + 1

    plugins = make(Legacy("legacy"))
    assert plugins.policy("legacy").make_config({"gain": 2.0}).gain == 2.0
    assert plugins.metrics()["legacy_metric"].label == "legacy_metric"
    assert plugins.format_prompt("a", "p0", "legacy") == "<a>"
    np.testing.assert_array_equal(plugins.postprocess_action(np.zeros(7), context("legacy")), np.ones(7))
    np.testing.assert_array_equal(plugins.postprocess_action(np.zeros(7), context("noop")), np.zeros(7))


# -- provenance: what an episode's identity names ------------------------------------------------
def test_provenance_names_the_policys_plugin_and_every_global_episode_hook():
    class Clip(Named):
        @hookimpl
        def conflictbench_postprocess_action(self, action, context):
            return None

    base = make().provenance("noop")
    assert len(base) == 1 and base[0].startswith("conflictbench==")
    plugins = make(Clip("clip"))
    plugins._sources["clip"] = plugins.source("clip").__class__("lab-clip", "0.2")
    assert plugins.provenance("noop") == tuple(sorted({base[0], "lab-clip==0.2"}))

    # A plugin's policy: conflictbench's own rollout code is part of its identity too.
    plugins = make(Model("model"))
    plugins._sources["model"] = plugins.source("model").__class__("conflictbench-model", "1.4")
    assert plugins.provenance("model-a") == tuple(sorted({base[0], "conflictbench-model==1.4"}))


def test_registries_list_names_in_registration_order():
    class Late(Named):
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("z_first", compute=lambda pair: 0.0)
            register("a_second", compute=lambda pair: 0.0)

    names = list(make(Late("late")).metrics())
    assert names[:4] == ["tar", "early20_ts", "ts", "ams"] and names[4:] == ["z_first", "a_second"]
