"""``conflictbench [OVERRIDE ...]``: the Hydra application that composes a run, plays it and reports."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from conflictbench.core import (
    FAMILIES,
    LEVELS,
    PROMPT_CONDITIONS,
    UserError,
)
from conflictbench.core.errors import ONE_LINE_ERRORS
from conflictbench.core.plugins import Plugins
from conflictbench.core.words import counted

from .overrides import (
    GROUPS,
    check_group_overrides,
    check_known_keys,
    check_model_fields,
    default_model,
    group_choices,
)
from .rejected import out_not_yet_made, remove_hydra_output
from .run_options import checked_names, run_options

__all__ = ["GROUPS", "check_group_overrides", "check_model_fields", "command", "default_model", "group_choices"]

CONFIG_PACKAGE = "pkg://conflictbench.conf"


def register_model_configs(plugins: Plugins) -> None:
    """Make every registered policy a Hydra ``model`` option (its config dataclass as the schema)."""
    from hydra.core.config_store import ConfigStore

    store = ConfigStore.instance()
    for name, spec in plugins.policies().items():
        store.store(group="model", name=name, node=spec.config if spec.config is not None else {})


#: ``finish(store, episode_ids)``: what a verb built on the run reports instead of the conflict tables.
Finish = Callable[[Any, list[str]], None]


def run_job(
    cfg: DictConfig, plugins: Plugins, model: str, *, declared: str | None = None, finish: Finish | None = None
) -> int:
    """Play the composed run and print its report (``finish``'s, where given); ``declared``: the published
    checkpoint the user declared the model to be, kept beside the episodes. Returns the process exit code."""
    from conflictbench.cli.sweep import record_job, sweep_job
    from conflictbench.report import report_store
    from conflictbench.sim.plan import build_plan
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore
    from conflictbench.tasks.libero.base_tasks import all_base_tasks
    from conflictbench.tasks.suite.file import load_suite

    options = run_options(cfg.run)
    families = checked_names(cfg.suite.families, "conflict family", FAMILIES)
    levels = checked_names(cfg.level.levels, "level", LEVELS)
    prompts = checked_names(cfg.prompt.conditions, "prompt condition", PROMPT_CONDITIONS)
    spec = plugins.policy(model)
    for name, why in plugins.load_failures.items():  # e.g. a global post-processor the user counts on
        print(
            f"conflictbench: warning: plugin {name} failed to load and takes no part in this run: {why}",
            file=sys.stderr,
        )
    settings = OmegaConf.to_container(cfg.model, resolve=True) if cfg.get("model") is not None else {}
    config = spec.make_config(settings or {})
    if options.metrics is not None:
        from conflictbench.report.summary import select_metrics

        select_metrics(plugins, options.metrics)  # fail now on an unknown name, not after the rollouts

    suite = load_suite(cfg.suite.get("file"))
    if cfg.suite.get("file"):
        check_suite_file(suite, plugins)  # the shipped suite was checked when it was built (its checksum holds)
    tasks = {t.key: t.language for t in all_base_tasks(tuple(options.libero_suites))}
    plan = build_plan(
        suite.cases,
        base_instructions=tasks,
        families=families,
        levels=levels,
        prompts=prompts,
        init_states=options.init_states,
        cases_per_cell=options.cases_per_cell,
        sample_seed=options.sample_seed,
        libero_suites=options.libero_suites,
        case_ids=options.cases,
        base_tasks=options.tasks,
        conflict_suite=suite.label,
    )
    if not plan:
        raise UserError(
            "this selection plans no episodes (no accepted case matches the suite/level/LIBERO-suite filters)"
        )
    store = EpisodeStore(options.out)
    from conflictbench.hosting.launch import SERVER_LOG_DIR_VARIABLE

    os.environ[SERVER_LOG_DIR_VARIABLE] = os.path.abspath(store.server_log_dir())  # beside the episodes
    conflicts = sum(e.case is not None for e in plan)
    print(
        f"conflictbench: model={model} suite={'+'.join(families)} level={'+'.join(levels)} "
        f"prompt={'+'.join(prompts)}: {counted(len(plan), 'episode')} ({conflicts} conflict, "
        f"{len(plan) - conflicts} reference) "
        f"from suite {suite.name} {suite.version}; store {store.root}/"
        + (f"; every episode capped at {n} steps (run.max_steps)" if (n := options.max_steps) else ""),
        file=sys.stderr,
    )
    from conflictbench.metrics.design import plan_line

    if line := plan_line(plan, families):
        print(f"conflictbench: {line}", file=sys.stderr)
    runner = Runner(
        plugins,
        spec,
        config,
        store=store,
        workers=options.workers,
        seed=options.seed,
        progress=options.progress,
        backend=options.backend,
        ray_address=options.ray_address,
        retry=options.retry,
        stall_timeout_s=options.stall_timeout_s,
        max_steps=options.max_steps,
    )
    result = runner.run(plan)
    if declared is not None:  # by the identity the runner computed: not part of it, so episodes are reused
        from conflictbench.store.declarations import record_declaration

        record_declaration(store.root, model, runner.config_hash, declared)
    print(
        f"conflictbench: {result.played} played, {result.already_stored} already stored, "
        f"{result.played_elsewhere} played by another job, {result.errors} with errors"
        + (f", {n} played again after their worker was lost" if (n := result.replayed_after_loss) else ""),
        file=sys.stderr,
    )
    job = sweep_job()
    report_dir = store.root / "report"
    if job is not None:  # a sweep's jobs keep their own tables apart; the sweep's end reports them together
        record_job(job[0], store.root, model, list(result.episode_ids))
        report_dir = report_dir / "jobs" / f"{job[1]}-{model}"
    if finish is not None:
        finish(store, list(result.episode_ids))
    elif options.report:
        whole_store = job is None  # a sweep's job writes its own tables; the sweep's end, the combined ones
        report_store(store, plugins, episode_ids=result.episode_ids, metrics=options.metrics,
                     out_dir=None if whole_store else report_dir, print_legend=whole_store)  # fmt: skip
        if whole_store:  # the files describe every model stored (as `report DIR` does), not just this run's
            import io

            report_store(store, plugins, out_dir=report_dir, metrics=options.metrics, stream=io.StringIO(),
                         suite=suite.label, suite_cases={c.case_id for c in suite.accepted()})  # fmt: skip
            print(f"the store's report (every model in {store.root}/) written to {report_dir}/")
    return 0


class PluginsHere:
    """The plugins of this process, for a job's task function: a launcher that runs jobs in other processes or on
    other machines (submitit, Ray) pickles the task, and there the job finds the installed plugins itself."""

    def __init__(self, plugins: Plugins | None):
        self.plugins = plugins

    def __getstate__(self) -> dict:
        # The plugins the user disabled travel with the job: a node elsewhere may not share our environment.
        return {"disabled": list(self.plugins.disabled_requested) if self.plugins is not None else None}

    def __setstate__(self, state: dict) -> None:
        self.plugins, self.disabled = None, state.get("disabled")

    def get(self) -> Plugins:
        if getattr(self, "plugins", None) is None:  # (pickle protocols < 2 never call __setstate__ for {})
            import conflictbench

            disabled = getattr(self, "disabled", None)
            self.plugins = conflictbench.plugins() if disabled is None else conflictbench.plugins(disabled=disabled)
        return self.plugins


def command(argv: list[str], plugins: Plugins) -> int:
    """Compose the run from Hydra overrides and play it (Hydra's own errors exit with code 2)."""
    from .published import take_declaration

    argv, declared = take_declaration(argv, plugins)
    return play(argv, plugins, declared=declared)


def play(argv: list[str], plugins: Plugins, *, declared: str | None = None, finish: Finish | None = None) -> int:
    """:func:`command` with the declaration already taken off ``argv``, and ``finish`` for :func:`run_job`."""
    import hydra
    from hydra.core.hydra_config import HydraConfig

    from conflictbench.cli import sweep
    from conflictbench.cli.sweep import record_failure, sweep_job

    register_model_configs(plugins)
    check_group_overrides(argv, plugins)
    check_model_fields(argv, plugins)
    check_known_keys(argv)
    state = {"started": False}
    here = PluginsHere(plugins)
    new_out = out_not_yet_made(argv)

    @hydra.main(version_base=None, config_path=CONFIG_PACKAGE, config_name="config")
    def task(cfg) -> int:
        state["started"] = True
        try:
            model = HydraConfig.get().runtime.choices["model"]
            return run_job(cfg, here.get(), model, declared=declared, finish=finish)
        except ONE_LINE_ERRORS as exc:
            print(f"conflictbench: error: {exc}", file=sys.stderr)
            hydra_config, job = HydraConfig.get(), sweep_job()
            if job is not None:  # the sweep goes on; its end says which jobs failed (and takes the record back)
                record_failure(job[0], job[1], exc.exit_code, str(exc))
            if isinstance(exc, UserError):  # a rejected command leaves nothing behind, not even Hydra's folder
                remove_hydra_output(Path(hydra_config.runtime.output_dir), Path(cfg.run.out), hydra_config.job.name)
                if new_out is not None and Path(os.path.abspath(cfg.run.out)) == new_out:
                    with contextlib.suppress(OSError):
                        new_out.rmdir()  # made for this command (by Hydra, by the store): only where empty
            if job is not None:
                return exc.exit_code
            raise SystemExit(exc.exit_code) from None

    saved = sys.argv
    sys.argv = ["conflictbench", *hydra_argv(argv)]
    sweep.failed_exit_code = 0
    try:
        task()
    except SystemExit as exc:
        if exc.code == 1 and not state["started"] and not sweep.failed_exit_code:
            return 2  # Hydra rejected an override; it has printed why
        return int(exc.code or 0)
    finally:
        sys.argv = saved
        if new_out is not None and sweep.failed_exit_code == 2:  # a sweep's record is taken back at its end
            with contextlib.suppress(OSError):
                new_out.rmdir()  # only where empty
    return sweep.failed_exit_code  # a sweep whose jobs failed (each said why)


def check_suite_file(suite, plugins: Plugins) -> None:
    """A user's suite file is played only if every case keeps the suite's rules (``suite validate``'s check)."""
    from conflictbench.tasks.validation.rules import new_context, validate_cases

    failures = validate_cases(suite.cases, new_context(None, plugins.conflict_operators().values()),
                              composition=bool(suite.version))  # fmt: skip
    if failures:
        bad = len({case_id for case_id, _ in failures})
        case_id, reason = failures[0]
        raise UserError(
            f"{suite.path}: {bad} of {len(suite.cases)} cases break the suite's rules (e.g. {case_id}: {reason}); "
            f"`conflictbench suite validate {suite.path}` lists them all"
        )


#: Hydra's flags without a value, and those with one: they may stand anywhere on our command line (Hydra's
#: parser wants them before the overrides).
HYDRA_SWITCHES = ("-m", "--multirun", "-r", "--run", "--resolve", "--version", "--help", "-h", "--hydra-help")
HYDRA_VALUE_FLAGS = ("-c", "--cfg", "-p", "--package", "-cn", "--config-name", "-cp", "--config-path",
                     "-cd", "--config-dir", "--experimental-rerun", "-i", "--info")  # fmt: skip
INFO_TOPICS = ("all", "config", "defaults", "defaults-tree", "plugins", "searchpath")


def hydra_argv(argv: Sequence[str]) -> list[str]:
    """Our command line as Hydra's: its flags first (each with its value), ``--config-help`` as Hydra's
    ``--help`` (the composed configuration and its groups); ``--hydra-help`` stays Hydra's own."""
    argv = [("--help" if a == "--config-help" else a) for a in argv]
    flags, rest, i = [], [], 0
    while i < len(argv):
        arg = argv[i]
        takes_value = arg in HYDRA_VALUE_FLAGS and i + 1 < len(argv)
        if takes_value and arg in ("-i", "--info") and argv[i + 1] not in INFO_TOPICS:
            takes_value = False  # --info's topic is optional
        if takes_value:
            flags += argv[i : i + 2]
            i += 2
            continue
        (flags if arg in HYDRA_SWITCHES or arg in HYDRA_VALUE_FLAGS or arg.startswith("--") else rest).append(arg)
        i += 1
    return [*flags, *rest]
