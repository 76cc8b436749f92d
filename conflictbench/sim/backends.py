"""Where a run's simulator workers run (``run.backend``): the one place that chooses between processes on this
machine (:mod:`.pool`, :mod:`.stack`) and Ray actors on a cluster (:mod:`.ray_pool`, imported only for Ray)."""

from __future__ import annotations

from . import stack
from .libero_env import EnvSettings
from .pool import WorkerPool


def make_pool(settings: EnvSettings, size: int, backend: str = "local", ray_address: str | None = None) -> WorkerPool:
    """A run's workers: processes here, or Ray actors on a cluster."""
    if backend == "ray":
        from .ray_pool import RayWorkerPool

        return RayWorkerPool(settings, size, address=ray_address)
    return WorkerPool(settings, size)


def probe_stack(settings: EnvSettings, backend: str = "local", ray_address: str | None = None) -> dict[str, str]:
    """The stack below the policy where a run's workers will run: a worker-like process here, or a Ray task on the
    cluster (the driver's machine need not be one of its nodes)."""
    if backend == "ray":
        from .ray_pool import probe_on_cluster

        return probe_on_cluster(settings, ray_address)
    return stack.probe_in_worker(settings)  # looked up when called: a test puts a probe of another machine there


def release_probe(backend: str = "local") -> None:
    """End what :func:`probe_stack` left open that no pool took over (Ray: the connection to the cluster)."""
    if backend == "ray":
        from .ray_pool import release_probe_connection

        release_probe_connection()
