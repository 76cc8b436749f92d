"""Moved: openpi's websocket transport is conflictbench's own,
:mod:`conflictbench.hosting.openpi` (kept importable here)."""

from conflictbench.hosting.openpi import OpenpiTransport

__all__ = ["OpenpiTransport"]
