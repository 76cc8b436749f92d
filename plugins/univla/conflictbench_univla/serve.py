"""What ``conflictbench-serve`` hosts from this plugin: a UniVLA checkpoint, UniVLA's code read from ``UNIVLA_CODE``.

Found through this plugin's entry point in the group ``conflictbench_serving``; the model environment runs it.
"""

from __future__ import annotations

from conflictbench_serving.command import ServedModel

from .checkpoints import check_checkpoint, check_code


def check(folder, policy: str, naming: str) -> None:
    check_code()  # the model's code, from the checkout UNIVLA_CODE names
    check_checkpoint(folder)


SERVED = ServedModel.of(
    __package__,
    policies=("univla",),
    protocol="our REST protocol (json-numpy)",
    check=check,
    url_scheme="http",
    checkpoint_help="a UniVLA checkpoint folder: the VLA in Hugging Face format and action_decoder.pt",
)
