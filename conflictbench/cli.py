"""The ``conflictbench`` command.

    conflictbench [hydra overrides]      compose and play a run (``-m`` for sweeps)
    conflictbench list                   policies, metrics, families, levels, prompts, presets
    conflictbench report DIR             tables from an episode store, running nothing
    conflictbench suite ...              validate, inspect, sample, export or rebuild the conflict suite

A mistake of the user's prints one line and exits with code 2; a simulator that cannot run
here prints what to install, and a policy server that cannot be reached is named by its URL;
both exit with code 3.
"""

from __future__ import annotations

import sys
from importlib import resources
from typing import Sequence

from conflictbench.core import ServerUnavailable, SimulatorUnavailable, UserError
from conflictbench.core.plugins import Plugins, unknown_choice

VERBS = ("list", "report", "suite")
USAGE = """usage: conflictbench [OVERRIDE ...]        play a run, e.g. model=noop suite=physical prompt=p1
       conflictbench -m [OVERRIDE ...]     sweep, e.g. -m model=noop,random prompt=p0,p1
       conflictbench list                  what can be chosen, and which package provides it
       conflictbench report DIR            tables from the episode store in DIR
       conflictbench suite validate|stats|sample|export|build ...   the conflict suite (see: suite --help)
       conflictbench --hydra-help          Hydra's own options
"""


def group_choices(group: str, plugins: Plugins) -> list[str]:
    """The options of a config group: registered policies for ``model``, YAML files otherwise."""
    if group == "model":
        return sorted(plugins.policies())
    folder = resources.files("conflictbench.conf") / group
    return sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml"))


def check_group_overrides(argv: Sequence[str], plugins: Plugins) -> None:
    """Reject ``group=unknown`` before Hydra composes anything (one line, exit code 2)."""
    from conflictbench.app import GROUPS

    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.lstrip("+~").split("=", 1)
        if key not in GROUPS or any(ch in value for ch in "()[]{}*$"):
            continue  # a field override or a sweep function: Hydra checks those
        choices = group_choices(key, plugins)
        for item in value.split(","):
            if item.strip() not in choices:
                failures = plugins.load_failures if key == "model" else None
                raise UserError(unknown_choice(key, item.strip(), choices, failures))


def _hydra_main(argv: list[str], plugins: Plugins) -> int:
    import hydra
    from hydra.core.hydra_config import HydraConfig

    from conflictbench.app import CONFIG_PACKAGE, register_model_configs, run_job

    register_model_configs(plugins)
    check_group_overrides(argv, plugins)
    state = {"started": False}

    @hydra.main(version_base=None, config_path=CONFIG_PACKAGE, config_name="config")
    def task(cfg) -> int:
        state["started"] = True
        try:
            return run_job(cfg, plugins, HydraConfig.get().runtime.choices["model"])
        except (UserError, SimulatorUnavailable, ServerUnavailable) as exc:
            print(f"conflictbench: error: {exc}", file=sys.stderr)
            raise SystemExit(exc.exit_code) from None

    saved = sys.argv
    sys.argv = ["conflictbench", *[("--help" if a == "--hydra-help" else a) for a in argv]]
    try:
        task()
    except SystemExit as exc:
        if exc.code == 1 and not state["started"]:
            return 2  # Hydra rejected an override; it has printed why
        return int(exc.code or 0)
    finally:
        sys.argv = saved
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] in (["-h"], ["--help"], ["help"]):
            print(USAGE, end="")
            return 0
        import conflictbench

        plugins = conflictbench.plugins()
        if argv[:1] == ["list"]:
            from conflictbench.verbs import list_command

            return list_command(argv[1:], plugins)
        if argv[:1] == ["report"]:
            from conflictbench.verbs import report_command

            return report_command(argv[1:], plugins)
        if argv[:1] == ["suite"]:
            from conflictbench.suite_verbs import suite_command

            return suite_command(argv[1:], plugins)
        return _hydra_main(argv, plugins)
    except (UserError, SimulatorUnavailable, ServerUnavailable) as exc:
        print(f"conflictbench: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # output piped into `head` and the like
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print("\nconflictbench: interrupted; every finished episode is stored, and the same command resumes the run",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
