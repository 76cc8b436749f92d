"""``conflictbench list``: what can be chosen, and which package provides it."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

from conflictbench.cli.args import Parser
from conflictbench.cli.overrides import group_choices
from conflictbench.core import FAMILIES, LEVELS, PROMPT_CONDITIONS
from conflictbench.core.plugins import Plugins


def command(argv: Sequence[str], plugins: Plugins) -> int:
    Parser(prog="conflictbench list", description="What can be chosen, and where it comes from.").parse_args(argv)
    from conflictbench.tasks.suite.file import load_suite

    print("policies (model=...):")
    for name, spec in sorted(plugins.policies().items()):
        print(f"  {name:<20} {spec.plugin} {spec.plugin_version}")
    published = plugins.published_results()
    print("published LIBERO results (conflictbench reproduce ... model.published=...; [paper: X]: the paper's X,")
    print("  whose figures then sit beside the run's):")
    if not published:
        print("  (none registered)")
    for name, result in published.items():
        suites = ", ".join(result.success)
        notes = ([f"[paper: {result.paper_model}]"] if result.paper_model else []) + (
            ["[secondary]"] if result.status != "primary" else []
        )
        players = " ".join(f"model={p}" for p in (result.policy, *result.played_by))
        print(f"  {name:<42} {players}  {' '.join([suites, *notes])}")
    print("metrics (per pair):")
    metrics = plugins.metrics()
    if not metrics:
        print("  (none registered)")
    for name, spec in sorted(metrics.items()):
        print(f"  {name:<20} {spec.plugin} {spec.plugin_version}  {spec.description}")
    suite = load_suite()
    counts = Counter((c.family, c.level) for c in suite.accepted())
    print(f"conflict families (suite=...), cases per level in {suite.name} {suite.version}:")
    for family in FAMILIES:
        per_level = "  ".join(f"{level}:{counts[(family, level)]}" for level in LEVELS)
        print(f"  {family:<20} {per_level}")
    print(f"levels (level=...): {', '.join(group_choices('level', plugins))}")
    print(
        f"prompt conditions (prompt=...): {', '.join(group_choices('prompt', plugins))} "
        f"(conditions: {', '.join(PROMPT_CONDITIONS)})"
    )
    print(f"run presets (run=...): {', '.join(group_choices('run', plugins))}")
    hooks = plugins.global_hook_plugins()
    print("global hooks (run for every policy; each such plugin is part of every episode's identity):")
    if not hooks:
        print("  (none installed)")
    for pin, names in sorted(hooks.items()):
        print(f"  {pin:<30} {', '.join(names)}")
    if plugins.disabled:
        print("plugins disabled (--disable-plugins, CONFLICTBENCH_DISABLE_PLUGINS; not imported):")
        for name, source in sorted(plugins.disabled.items()):
            print(f"  {name:<20} {source.distribution} {source.version}")
    if plugins.load_failures:
        print("plugins that failed to load:")
        for name, why in plugins.load_failures.items():
            print(f"  {name}: {why}")
    return 0
