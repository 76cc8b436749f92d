"""Fixtures of the gr00t plugin's tests, each defined in its own module and gathered here."""

from groot_model_env import tiny_groot_checkpoint  # noqa: F401
