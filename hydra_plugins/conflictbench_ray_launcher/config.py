"""The launcher's settings, registered as ``hydra/launcher=ray`` (Hydra reads this module when it looks for plugins)."""

# No `from __future__ import annotations`: Hydra runs this module outside sys.modules, and the dataclass and
# OmegaConf read the annotations as types.
from dataclasses import dataclass
from typing import Optional

from hydra.core.config_store import ConfigStore


@dataclass
class RayLauncherConf:
    _target_: str = "hydra_plugins.conflictbench_ray_launcher.ray_launcher.RayLauncher"
    address: Optional[str] = None  # noqa: UP045 (OmegaConf 2.3 reads Optional, not X | None)
    """The cluster (``ray://`` or ``host:port``); null: ``RAY_ADDRESS``, else Ray started on this machine."""
    cpus_per_job: float = 2
    """A job's simulator workers are processes where it runs: give it ``run.workers`` CPUs."""
    gpus_per_job: float = 0
    """For a job whose policy runs in its own process on the GPU (a served policy's server)."""


ConfigStore.instance().store(group="hydra/launcher", name="ray", node=RayLauncherConf, provider="conflictbench")
