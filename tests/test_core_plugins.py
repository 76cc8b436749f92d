"""The plugin contract: registries, attribution, prompt formatting and the post-processing chain."""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import conflictbench
from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import (
    P1_PREAMBLE,
    ActionContext,
    PluginError,
    Plugins,
    PolicyError,
    UserError,
    as_action_chunk,
)

CONTEXT = ActionContext(policy="p", suite="libero_goal", task_id=0, prompt="p0", case_id=None, step=3, chunk_index=0)


def make(*extra) -> Plugins:
    return Plugins(BUILTIN_PLUGINS, entry_points=False, extra=extra)


def test_builtin_policies_register_through_the_hook_and_name_their_package():
    specs = make().policies()
    assert {"noop", "random"} <= set(specs)
    assert specs["noop"].plugin == "conflictbench"
    assert specs["random"].config is not None and specs["noop"].config is None


def test_policy_config_fields_become_settings_and_unknown_ones_are_refused():
    spec = make().policy("random")
    cfg = spec.make_config({"seed": 5})
    assert cfg.seed == 5 and cfg.scale == 1.0
    with pytest.raises(UserError, match="unknown setting.*colour.*valid: scale, seed"):
        spec.make_config({"colour": 1})
    with pytest.raises(UserError, match="takes no settings"):
        make().policy("noop").make_config({"x": 1})


def test_unknown_policy_names_the_choices():
    with pytest.raises(UserError, match=r"unknown model 'nope'; valid choices: noop, oracle, random, scripted"):
        make().policy("nope")


def test_duplicate_names_and_bad_registrations_are_plugin_errors():
    class Dup:
        @hookimpl
        def conflictbench_register_policies(self, register):
            register("noop", load=lambda cfg: None)

    with pytest.raises(PluginError, match="'noop' registered twice"):
        make(Dup()).policies()

    class BadConfig:
        @hookimpl
        def conflictbench_register_policies(self, register):
            register("x", load=lambda cfg: None, config=dict)

    with pytest.raises(PluginError, match="config must be a dataclass"):
        make(BadConfig()).policies()

    class BadName:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("has space", compute=lambda pair: 0.0)

    with pytest.raises(PluginError, match="not valid"):
        make(BadName()).metrics()


def test_format_prompt_default_and_first_result_wins():
    plugins = make()
    assert plugins.format_prompt("open the drawer", "p0", "noop") == "open the drawer"
    p1 = plugins.format_prompt("open the drawer", "p1", "noop")
    assert p1.startswith(P1_PREAMBLE) and p1.endswith("open the drawer")
    with pytest.raises(UserError, match="unknown prompt condition 'p2'"):
        plugins.format_prompt("x", "p2", "noop")

    class Shout:
        @hookimpl
        def conflictbench_format_prompt(self, instruction, condition, policy):
            return instruction.upper() if policy == "loud" else None

    plugins = make(Shout())
    assert plugins.format_prompt("open", "p0", "loud") == "OPEN"
    assert plugins.format_prompt("open", "p0", "noop") == "open"  # falls back to the core's default


def test_postprocess_chain_runs_in_documented_order_and_keeps_none_as_unchanged():
    calls = []

    def post(name, fn, **marks):
        class P:
            @hookimpl(**marks)
            def conflictbench_postprocess_action(self, action, context):
                calls.append(name)
                return fn(action)

        P.__name__ = name
        return P()

    first = post("first", lambda a: a + 1, tryfirst=True)
    plain_a = post("plain_a", lambda a: a * 2)
    plain_b = post("plain_b", lambda a: None)
    last = post("last", lambda a: a - 3, trylast=True)
    plugins = make(last, plain_a, plain_b, first)  # registration order a, b: b is called before a
    out = plugins.postprocess_action(np.zeros(7), CONTEXT)
    assert calls == ["first", "plain_b", "plain_a", "last"]
    np.testing.assert_array_equal(out, np.full(7, (0 + 1) * 2 - 3.0))


def test_postprocess_returning_a_wrong_shape_is_a_policy_error():
    class Bad:
        @hookimpl
        def conflictbench_postprocess_action(self, action, context):
            return action[:3]

    with pytest.raises(PolicyError, match=r"shape \(3,\)"):
        make(Bad()).postprocess_action(np.zeros(7), CONTEXT)


@pytest.mark.parametrize(
    "raw, message",
    [
        (np.zeros(6), "shape"),
        (np.zeros((2, 3)), "shape"),
        (np.zeros((0, 7)), "shape"),
        ([0, 0, 0, float("nan"), 0, 0, 0], "non-finite"),
        ([float("inf")] * 7, "non-finite"),
        ("left", "numeric"),
    ],
)
def test_bad_policy_outputs_are_rejected(raw, message):
    with pytest.raises(PolicyError, match=message):
        as_action_chunk(raw)


def test_single_actions_and_chunks_become_chunks():
    assert as_action_chunk(np.arange(7)).shape == (1, 7)
    chunk = as_action_chunk(np.ones((5, 7), dtype=np.float32))
    assert chunk.shape == (5, 7) and chunk.dtype == np.float64


def test_register_callbacks_attribute_each_plugin():
    @dataclass
    class Cfg:
        depth: int = 2

    class Mine:
        @hookimpl
        def conflictbench_register_policies(self, register):
            register("mine", load=lambda cfg: cfg, config=Cfg)

        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("m1", compute=lambda pair: 1.0, description="one")

    plugins = make(Mine())
    assert plugins.policy("mine").plugin == "(in-process)"
    assert plugins.metrics()["m1"].description == "one"
    assert plugins.policy("mine").make_config({"depth": 4}).depth == 4


def fake_distribution(site: Path, name: str, entry_points: str, version: str = "1.0") -> None:
    """An installed distribution as importlib.metadata sees it: a dist-info with its entry points."""
    info = site / f"{name.replace('-', '_')}-{version}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    (info / "entry_points.txt").write_text(f"[conflictbench]\n{entry_points}\n")


SHARED_HELPER = """
from conflictbench import hookimpl

class Registers:
    def __init__(self, policy):
        self.policy = policy

    @hookimpl
    def conflictbench_register_policies(self, register):
        register(self.policy, load=lambda cfg: None)
"""


def test_two_plugins_sharing_a_helper_are_each_named_as_the_source_of_their_own_registrations(tmp_path, monkeypatch):
    (tmp_path / "shared_registers.py").write_text(SHARED_HELPER)
    for name in ("alpha", "beta"):
        module = f"from shared_registers import Registers\nplugin = Registers({name!r})\n"
        (tmp_path / f"{name}_plugin.py").write_text(module)
        fake_distribution(tmp_path, f"{name}-plugin", f"{name} = {name}_plugin:plugin")
    monkeypatch.syspath_prepend(str(tmp_path))
    plugins = conflictbench.plugins()
    assert (plugins.policy("alpha").plugin, plugins.policy("beta").plugin) == ("alpha-plugin", "beta-plugin")


def test_a_register_callback_kept_and_called_later_is_refused():
    kept = []

    class Late:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            kept.append(register)

    plugins = make(Late())
    assert "late" not in plugins.metrics() and len(kept) == 1
    with pytest.raises(PluginError, match="after its implementation returned"):
        kept[0]("late", compute=lambda pair: 1.0)


def test_a_plugin_that_fails_to_import_is_reported_not_fatal(tmp_path, monkeypatch):
    dist = tmp_path / "broken_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[conflictbench]\nbroken = broken_plugin_module_that_is_missing\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    plugins = conflictbench.plugins()
    assert "noop" in plugins.policies()
    ((name, why),) = plugins.load_failures.items()
    assert "broken-plugin" in name and "ModuleNotFoundError" in why
    with pytest.raises(UserError, match="plugins that failed to load: broken"):
        plugins.policy("whatever")


def test_core_imports_nothing_else_of_ours_nor_heavy_libraries():
    """Nor, relatively, anything above it (``from ..x``): the names that moved up to ``conflictbench.hosting`` are
    found from here by a ``__getattr__`` that ``hosting`` sets, so core needs no import of it."""
    core = Path(conflictbench.__file__).parent / "core"
    above = []
    for path in core.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level > 1:
                above.append((path.name, node.module, [alias.name for alias in node.names]))
                continue
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                assert not name.startswith("conflictbench"), f"{path.name} imports {name}"
                assert name.split(".")[0] not in {"libero", "robosuite", "mujoco", "torch", "pandas", "hydra"}, (
                    f"{path.name} imports {name}"
                )
    assert above == []


def test_a_register_call_with_wrong_arguments_names_the_plugin():
    class Sloppy:
        @hookimpl
        def conflictbench_register_metrics(self, register):
            register("m2", lambda pair: 0.0, "desc", "one too many")

    with pytest.raises(PluginError, match=r"metric 'm2' from .*Sloppy.*positional argument"):
        make(Sloppy()).metrics()


def test_a_disabled_plugin_is_not_imported_and_leaves_the_identity(tmp_path, monkeypatch):
    (tmp_path / "clipping_plugin.py").write_text(
        "import numpy as np\nfrom conflictbench import hookimpl\nIMPORTED = True\n\n"
        "@hookimpl\ndef conflictbench_postprocess_action(action, context):\n    return np.clip(action, -0.5, 0.5)\n"
    )
    fake_distribution(tmp_path, "clipping-plugin", "clipping = clipping_plugin")
    monkeypatch.syspath_prepend(str(tmp_path))
    on = conflictbench.plugins(disabled=[])
    assert "clipping-plugin==1.0" in on.provenance("noop")
    # what else is installed keeps its hooks: only the disabled plugin's go
    others = {name: hooks for name, hooks in on.global_hook_plugins().items() if name != "clipping-plugin==1.0"}
    import sys

    sys.modules.pop("clipping_plugin", None)
    for name in ("clipping", "Clipping_Plugin"):  # an entry point's name, or its distribution's as PyPI compares
        off = conflictbench.plugins(disabled=[name])
        assert "clipping_plugin" not in sys.modules
        assert off.disabled["clipping"].distribution == "clipping-plugin"
        assert off.global_hook_plugins() == others and "clipping-plugin==1.0" not in off.provenance("noop")
    monkeypatch.setenv("CONFLICTBENCH_DISABLE_PLUGINS", "clipping")
    assert "clipping" in conflictbench.plugins().disabled
    with pytest.raises(UserError, match="cannot disable clippin: no installed plugin .*installed plugins: .*clipping"):
        conflictbench.plugins(disabled=["clippin"])


def test_a_jobs_pickled_plugins_keep_the_disabled_ones(tmp_path, monkeypatch):
    import pickle

    from conflictbench.cli.run import PluginsHere

    fake_distribution(tmp_path, "clipping-plugin", "clipping = clipping_plugin_never_imported")
    monkeypatch.syspath_prepend(str(tmp_path))
    here = PluginsHere(conflictbench.plugins(disabled=["clipping"]))
    elsewhere = pickle.loads(pickle.dumps(here))  # a launcher's node, without our environment variable
    assert elsewhere.plugins is None and list(elsewhere.get().disabled) == ["clipping"]
    assert elsewhere.get().load_failures == {}
