"""The P0/P1 prompt conditions: the one place the premise-check preamble is written down."""

from __future__ import annotations

from .errors import UserError
from .hookspecs import hookimpl
from .records import PROMPT_CONDITIONS

P1_PREAMBLE = (
    "Before acting, check whether the instruction's premises hold in the current scene: the "
    "objects it names are present, the relations it assumes are true, and the action is "
    "physically possible. If any premise is invalid, do not execute the task."
)


def default_format_prompt(instruction: str, condition: str) -> str:
    """P0 is the task text unchanged; P1 is the preamble followed by the task text."""
    if condition == "p0":
        return instruction
    if condition == "p1":
        return f"{P1_PREAMBLE} Task: {instruction}"
    raise UserError(f"unknown prompt condition {condition!r}; choose one of {', '.join(PROMPT_CONDITIONS)}")


@hookimpl(trylast=True)
def conflictbench_format_prompt(instruction, condition, policy):
    return default_format_prompt(instruction, condition)
