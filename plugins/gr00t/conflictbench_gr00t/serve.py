"""What ``conflictbench-serve`` hosts from this plugin: a LeRobot GR00T N1.7 checkpoint, on NVIDIA's port.

Found through this plugin's entry point in the group ``conflictbench_serving``; the model environment runs it.
"""

from __future__ import annotations

from conflictbench_serving.command import ServedModel

from .checkpoints import check_checkpoint

SERVED = ServedModel.of(
    __package__,
    policies=("gr00t",),
    protocol="NVIDIA's ZeroMQ protocol",
    check=lambda folder, policy, naming: check_checkpoint(folder),
    port=5555,
    url_scheme="tcp",
)
