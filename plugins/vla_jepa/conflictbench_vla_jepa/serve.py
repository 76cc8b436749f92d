"""What ``conflictbench-serve`` hosts from this plugin: a LeRobot VLA-JEPA checkpoint.

Found through this plugin's entry point in the group ``conflictbench_serving``; the model environment runs it.
"""

from __future__ import annotations

from conflictbench_serving.command import ServedModel

from .checkpoints import check_checkpoint

SERVED = ServedModel.of(__package__, policies=("vla-jepa",), protocol="VLA-JEPA's websocket protocol",
                        check=lambda folder, policy, naming: check_checkpoint(folder))  # fmt: skip
