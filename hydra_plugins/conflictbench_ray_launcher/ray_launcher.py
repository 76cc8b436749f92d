"""A Hydra launcher that runs each job of a sweep as a Ray task (one process per job, wherever Ray places it)."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, open_dict

log = logging.getLogger(__name__)


def run_one(
    hydra_context: HydraContext,
    task_function: TaskFunction,
    config: DictConfig,
    overrides: list[str],
    num: int,
    singletons: dict,
    cwd: str,
) -> JobReturn:
    """One job, in a Ray worker: Hydra's state as the launcher had it, the launcher's folder (relative
    ``run.out`` means the same there when the nodes share it), then Hydra's own ``run_job``."""
    import ray

    if not Path(cwd).is_dir():  # its relative paths (run.out, the sweep's folder) would land elsewhere
        from conflictbench.core import UserError

        raise UserError(f"the folder the sweep was launched from, {cwd}, is not on this node: share it")
    os.chdir(cwd)
    Singleton.set_state(singletons)
    setup_globals()
    sweep_config = hydra_context.config_loader.load_sweep_config(config, overrides)
    with open_dict(sweep_config.hydra.job) as job:
        job.id = f"ray_{ray.get_runtime_context().get_task_id()}"
        job.num = num
    return run_job(
        hydra_context=hydra_context,
        task_function=task_function,
        config=sweep_config,
        job_dir_key="hydra.sweep.dir",
        job_subdir_key="hydra.sweep.subdir",
    )


def lost_job(num: int, job_dir: Path, error: Exception) -> JobReturn:
    """A job whose task never returned (its process crashed, its node was lost, it could not start): named in
    one line, recorded for the sweep's end (which sets the command's exit code), the other jobs kept."""
    from conflictbench.cli.sweep import record_failure
    from conflictbench.core import SimulatorUnavailable

    cause = getattr(error, "cause", None)  # a RayTaskError's own exception
    if hasattr(cause, "exit_code"):  # one of ours: a user's mistake (2), the simulator (3) ...
        message, exit_code = str(cause), cause.exit_code
    else:
        text = str(error).strip().splitlines()
        message = f"its Ray task was lost ({type(error).__name__}: {text[-1] if text else ''})"
        exit_code = SimulatorUnavailable.exit_code
    print(f"conflictbench: error: sweep job {num}: {message}", file=sys.stderr)
    job_dir.parent.mkdir(parents=True, exist_ok=True)
    record_failure(job_dir, num, exit_code, message)
    result = JobReturn(status=JobStatus.COMPLETED)
    result.return_value = exit_code
    return result


class RayLauncher(Launcher):
    def __init__(self, address: str | None = None, cpus_per_job: float = 2, gpus_per_job: float = 0) -> None:
        self.address, self.cpus_per_job, self.gpus_per_job = address, cpus_per_job, gpus_per_job
        self.config: DictConfig | None = None
        self.hydra_context: HydraContext | None = None
        self.task_function: TaskFunction | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config, self.hydra_context, self.task_function = config, hydra_context, task_function

    def _outcome(self, ray: Any, ref: Any, num: int) -> JobReturn:
        try:
            return ray.get(ref)
        except ray.exceptions.RayError as exc:  # RayTaskError (it raised), WorkerCrashedError, NodeDiedError ...
            return lost_job(num, Path(str(self.config.hydra.sweep.dir)) / str(num), exc)

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        import ray

        assert self.config is not None and self.hydra_context is not None and self.task_function is not None
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        log.info(f"Ray sweep output dir: {sweep_dir}")
        owns_ray = not ray.is_initialized()
        if owns_ray:
            from conflictbench.sim.ray_pool import connect

            connect(ray, self.address)  # a cluster nobody answers: one line at once
        job = ray.remote(num_cpus=self.cpus_per_job, num_gpus=self.gpus_per_job, max_retries=0)(run_one)
        try:
            pending = []
            for num, overrides in enumerate(job_overrides, start=initial_job_idx):
                log.info(f"\t#{num} : {' '.join(filter_overrides(overrides))}")
                pending.append(
                    job.remote(
                        self.hydra_context,
                        self.task_function,
                        self.config,
                        list(overrides),
                        num,
                        Singleton.get_state(),
                        os.getcwd(),
                    )
                )
            return [self._outcome(ray, ref, num) for num, ref in enumerate(pending, start=initial_job_idx)]
        finally:
            if owns_ray:
                ray.shutdown()
