"""The worker pool's bookkeeping that needs no simulator: one run, one simulator version."""

from __future__ import annotations

import pytest

from conflictbench.core import SimulatorUnavailable
from conflictbench.sim.libero_env import EnvSettings
from conflictbench.sim.pool import WorkerPool

VERSIONS = {"mujoco_version": "2.3.7", "robosuite_version": "1.4.0", "libero_version": "0.1.1"}


def test_workers_reporting_the_same_versions_are_accepted():
    pool = WorkerPool(EnvSettings(needs_images=False), size=2)
    pool.check_versions(VERSIONS)  # the first says what the run's are
    pool.versions = dict(VERSIONS)
    pool.check_versions(dict(VERSIONS))


def test_a_worker_with_another_simulator_version_stops_the_run_naming_the_difference():
    pool = WorkerPool(EnvSettings(needs_images=False), size=2)
    pool.versions = dict(VERSIONS)
    with pytest.raises(SimulatorUnavailable, match=r"mujoco_version: 2\.3\.7 vs 3\.3\.2\); install the same"):
        pool.check_versions(VERSIONS | {"mujoco_version": "3.3.2"})


@pytest.mark.parametrize(
    "address, target",
    [
        ("head:6379", ("head", 6379)),
        ("10.0.0.5:6379", ("10.0.0.5", 6379)),
        ("[::1]:6379", ("::1", 6379)),
        ("ray://head:10001", None),  # Ray Client: Ray connects and says why itself
        ("local", None),
        ("auto", None),
        (None, None),
    ],
)
def test_only_a_plain_host_and_port_is_checked_before_ray_connects(address, target):
    from conflictbench.sim.ray_pool import gcs_target

    assert gcs_target(address) == target
