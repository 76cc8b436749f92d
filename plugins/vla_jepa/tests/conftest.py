"""Fixtures of the vla_jepa plugin's tests, each defined in its own module and gathered here."""

from jepa_model_env import tiny_checkpoint  # noqa: F401
