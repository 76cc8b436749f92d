"""The lerobot plugin's published.toml: read as the registry reads every model plugin's (read_published, then
published_spec, which register() calls), model=lerobot, a LeRobot policy type named in each entry, and no entry
name another plugin's published.toml already registers. Read from the file, so it runs before the client module
(whose entry point registers it) exists."""

from __future__ import annotations

from pathlib import Path

import pytest

from conflictbench import read_published
from conflictbench.core.registry import PluginSource, published_spec

PLUGINS = Path(__file__).resolve().parents[2]
OURS = PLUGINS / "lerobot" / "conflictbench_lerobot" / "published.toml"

#: LeRobot 0.6.1's policy types (lerobot/policies/, docs/upstream/lerobot_policies.md).
LEROBOT_TYPES = {
    "act", "diffusion", "eo1", "evo1", "fastwam", "gaussian_actor", "groot", "lingbot_va", "molmoact2",
    "multi_task_dit", "pi0", "pi05", "pi0_fast", "smolvla", "tdmpc", "vla_jepa", "vqbet", "wall_x", "xvla",
}  # fmt: skip
#: Registered by the pi0, gr00t and vla_jepa plugins, LeRobot ports included.
ELSEWHERE = {"pi0", "pi05", "pi0_fast", "groot", "vla_jepa"}


@pytest.fixture(scope="module")
def entries():
    return read_published(OURS)


def test_the_registry_accepts_every_entry(entries):
    source = PluginSource("conflictbench-lerobot", "0.1.0")
    results = [published_spec(f"published.toml {e['name']}", source, **e) for e in entries]
    assert len({r.name for r in results}) == len(results) >= 2
    for result in results:
        assert result.policy == "lerobot", result.name
        assert result.paper_model is None, result.name  # the paper's eight models are other plugins'
        assert set(result.success) == {"libero_spatial", "libero_object", "libero_goal", "libero_10"}, result.name
        assert result.url.startswith("https://"), result.name


def test_each_entry_names_a_lerobot_type_this_plugin_adds(entries):
    types = set()
    for entry in entries:
        first = entry["caveats"][0]
        assert first.startswith("LeRobot policy type: "), entry["name"]
        kind = first.removeprefix("LeRobot policy type: ")
        assert kind in LEROBOT_TYPES - ELSEWHERE, entry["name"]
        types.add(kind)
    assert {"smolvla", "xvla"} <= types


def test_lerobot_eval_protocol(entries):
    """The base every LeRobot-docs entry extends: 360 px, 10 settle steps, budgets 280/280/300/520."""
    import tomllib

    base = tomllib.loads(OURS.read_text(encoding="utf-8"))["protocol"]["lerobot-eval"]
    assert base["warmup_steps"] == 10 and base["episodes_per_suite"] == 100
    assert base["max_steps"] == {"libero_spatial": 280, "libero_object": 280, "libero_goal": 300, "libero_10": 520}
    assert "360 x 360" in base["notes"] and "1000" in base["init_states"]
    evo1 = next(e for e in entries if e["name"] == "evo1-libero-lerobot")
    assert evo1["protocol"]["max_steps"] == base["max_steps"] and evo1["protocol"]["episodes_per_suite"] == 500


def test_no_entry_name_is_another_plugins(entries):
    others = {
        e["name"]
        for path in PLUGINS.glob("*/conflictbench_*/published.toml")
        if path != OURS
        for e in read_published(path)
    }
    assert others, "the other plugins' published.toml files were not found"
    assert not {e["name"] for e in entries} & others
