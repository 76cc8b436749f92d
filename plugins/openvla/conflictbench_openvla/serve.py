"""What ``conflictbench-serve`` hosts from this plugin: an OpenVLA checkpoint in Hugging Face format.

Found through this plugin's entry point in the group ``conflictbench_serving``; the model environment runs it.
"""

from __future__ import annotations

from conflictbench_serving.command import ServedModel

from .checkpoints import check_checkpoint

SERVED = ServedModel.of(
    __package__,
    policies=("openvla", "openvla-oft"),  # our server hosts OpenVLA; it refuses OFT in one line
    protocol="deploy.py's REST protocol (json-numpy)",
    check=lambda folder, policy, naming: check_checkpoint(folder, policy),
    url_scheme="http",
    checkpoint_help="an OpenVLA checkpoint folder in Hugging Face format (with its own model code)",
)
