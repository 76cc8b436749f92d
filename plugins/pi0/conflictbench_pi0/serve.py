"""What ``conflictbench-serve`` hosts from this plugin: the π checkpoints (pi0, pi05, pi0-fast).

Found through this plugin's entry point in the group ``conflictbench_serving``; the model environment runs it.
"""

from __future__ import annotations

from conflictbench_serving.command import ServedModel

from .checkpoints import POLICY_TYPES, check_checkpoint

SERVED = ServedModel.of(
    __package__,
    policies=tuple(POLICY_TYPES),
    protocol="openpi's websocket protocol",
    check=lambda folder, policy, naming: check_checkpoint(folder, policy, option=naming),
)
