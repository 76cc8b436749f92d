"""Fixtures of the univla plugin's tests, each defined in its own module and gathered here."""

from univla_model_env import tiny_checkpoint  # noqa: F401
