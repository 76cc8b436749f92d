"""A sweep's report: each job's tables in a folder of its own, and one report over every job at the end.

Each job of ``conflictbench -m ...`` records what it played (``conflictbench-job.json`` in its Hydra folder)
and writes its tables under ``<run.out>/report/jobs/<job>-<model>/`` (printing them without the legend, printed
once at the end); when the sweep ends, Hydra calls
:class:`CombinedReport`, which reports the episodes of all jobs together into ``<run.out>/report/``. It finds
the jobs' records below the sweep's folder (``hydra.sweep.dir``, on storage the jobs share): a sweep over
``run.out`` itself puts its jobs' folders elsewhere and gets only the per-job reports.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback

JOB_RECORD = "conflictbench-job.json"
FAILED_RECORD = "conflictbench-failed-{num}.json"  # in the sweep's folder (a rejected job's own folder goes)

#: The exit code of the sweep's failed jobs (the highest), for the command to return when the sweep ends.
failed_exit_code = 0


def sweep_job() -> tuple[Path, int] | None:
    """This job's Hydra folder and number, in a multirun; None in a single run."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    hydra = HydraConfig.get()
    if hydra.mode != RunMode.MULTIRUN:
        return None
    return Path(hydra.runtime.output_dir), int(hydra.job.num)


def record_failure(folder: Path, num: int, exit_code: int, message: str) -> None:
    """A sweep job that failed says so where the sweep's end finds it (a job on another machine prints into its
    own log only); the sweep goes on with its other jobs."""
    global failed_exit_code
    failed_exit_code = max(failed_exit_code, exit_code)  # a job in this process
    record = {"job": num, "exit_code": exit_code, "message": message, "pid": os.getpid(), "host": socket.gethostname()}
    (folder.parent / FAILED_RECORD.format(num=num)).write_text(json.dumps(record))


def collect_failures(sweep_dir: Path) -> list[dict]:
    """The failed jobs' records, taken away (a sweep folder no job kept then goes too: nothing written stays)."""
    global failed_exit_code
    paths = sorted(sweep_dir.glob(FAILED_RECORD.format(num="*")))
    failures = [json.loads(path.read_text()) for path in paths]
    for path in paths:
        path.unlink()
    if failures:
        failed_exit_code = max(failed_exit_code, *(f["exit_code"] for f in failures))
        if sweep_dir.is_dir() and [p.name for p in sweep_dir.iterdir()] == ["multirun.yaml"]:
            (sweep_dir / "multirun.yaml").unlink()
            for empty in (sweep_dir, sweep_dir.parent):  # the sweep's folder, then <run.out>/hydra if empty
                with contextlib.suppress(OSError):
                    empty.rmdir()
    return failures


def record_job(folder: Path, store_root: Path, model: str, episode_ids: list[str]) -> None:
    record = {"store": str(Path(store_root).resolve()), "model": model, "episode_ids": list(episode_ids)}
    (folder / JOB_RECORD).write_text(json.dumps(record))


class CombinedReport(Callback):
    """Hydra callback (``hydra.callbacks`` in the config): the report over every job of the sweep."""

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        here = (os.getpid(), socket.gethostname())
        failures = collect_failures(Path(config.hydra.sweep.dir))
        elsewhere = [f for f in failures if (f["pid"], f["host"]) != here]  # the others were printed here already
        for failure in elsewhere:
            print(f"conflictbench: error: sweep job {failure['job']}: {failure['message']}", file=sys.stderr)
        if not config.run.get("report", True):
            return
        jobs = [json.loads(path.read_text()) for path in sorted(Path(config.hydra.sweep.dir).rglob(JOB_RECORD))]
        if not jobs:
            return
        import conflictbench
        from conflictbench.report import report_store, select_metrics
        from conflictbench.report.summary import legend
        from conflictbench.store import EpisodeStore

        plugins = conflictbench.plugins()
        metrics = list(config.run.metrics) if config.run.get("metrics") is not None else None
        if len(jobs) < 2:  # one job's own report is the sweep's; the jobs leave the legend to the sweep's end
            print("\n" + legend(select_metrics(plugins, metrics)), file=sys.stdout)
            return
        by_store: dict[str, list[dict]] = defaultdict(list)
        for job in jobs:
            by_store[job["store"]].append(job)
        for root, store_jobs in by_store.items():
            ids = list(dict.fromkeys(i for job in store_jobs for i in job["episode_ids"]))
            models = ", ".join(dict.fromkeys(job["model"] for job in store_jobs))
            print(f"\n== the sweep's {len(store_jobs)} jobs together ({models}) ==", file=sys.stdout)
            store = EpisodeStore(root)
            report_store(store, plugins, episode_ids=ids, out_dir=store.root / "report", metrics=metrics)
