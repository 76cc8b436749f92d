"""Errors the framework raises on purpose.

The command line turns a :class:`UserError` into one line on stderr and exit code 2, and a
:class:`SimulatorUnavailable` into its install hint and exit code 3; anything else is a bug and
keeps its traceback.
"""

from __future__ import annotations


class ConflictbenchError(Exception):
    """Base class of every error conflictbench raises deliberately."""


class UserError(ConflictbenchError):
    """Bad input from the person running the tool: an unknown option, a malformed file."""

    exit_code = 2


class SimulatorUnavailable(ConflictbenchError):
    """LIBERO or its rendering stack cannot be used on this machine; the message says how to fix it."""

    exit_code = 3


class PolicyError(ConflictbenchError):
    """A policy misbehaved during an episode (raised, returned NaN/inf or the wrong shape).

    The episode is stored with this message as its ``error`` and counted as failed; the run goes on.
    """


class PluginError(ConflictbenchError):
    """A plugin registered something invalid (a duplicate name, a non-dataclass config)."""
