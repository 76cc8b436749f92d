"""Fixtures of the pi0 plugin's tests, each defined in its own module and gathered here."""

from server_fixtures import start_server  # noqa: F401
from tiny_fixtures import tiny_checkpoints, tiny_env  # noqa: F401
