"""Deprecated (goes in conflictbench 0.4.0): openpi's websocket transport moved to conflictbench's own
:mod:`conflictbench.hosting.openpi` in 0.3; reading a name here warns and gives that module's."""

from conflictbench.core.deprecation import moved_names

__getattr__ = moved_names(__name__, {"OpenpiTransport": "conflictbench.hosting.openpi:OpenpiTransport"})
__all__ = ["OpenpiTransport"]  # noqa: F822 (0.2's exports: a star import warns and works)
