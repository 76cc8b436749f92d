"""Fixtures of the openvla plugin's tests, each defined in its own module and gathered here."""

from openvla_model_env import tiny_checkpoint  # noqa: F401
