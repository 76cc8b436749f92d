"""Fixtures of the lerobot plugin's tests, defined in ``lerobot_fixtures`` and gathered here: a session fixture
imported into each test module is one fixture per module, and the six tiny checkpoints were built five times."""

from lerobot_fixtures import tiny_lerobot_checkpoints, tiny_lerobot_env  # noqa: F401
