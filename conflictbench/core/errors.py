"""Errors the framework raises on purpose.

The command line turns every error with an ``exit_code`` into one line on stderr and that exit
code: a :class:`UserError` or :class:`PluginError` 2, a :class:`SimulatorUnavailable`,
:class:`ServerUnavailable`, :class:`PolicyStalled` or :class:`StoreFull` 3; anything else is a bug and keeps its
traceback.
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

    kind = "policy"


class PluginError(ConflictbenchError):
    """A plugin registered something invalid (a duplicate name, a non-dataclass config) or implements
    a hook that does not exist; the message names the plugin."""

    exit_code = 2


class InfrastructureError(ConflictbenchError):
    """An episode failed for a reason that is not the model's behaviour: the policy server answered
    with an error (out of memory, an exception), or the connection kept failing on one request.

    The episode is stored with this message, left out of the measures like a simulator failure,
    and played again by the next run of the same command. Raise it from a served policy's
    transport or ``decode`` for a server's error reply.
    """

    kind = "server"


class ClientError(InfrastructureError):
    """A served policy's own processing failed on one episode (its ``encode`` raised, or its ``decode``
    could not read a reply): a bug or a mismatch in the client, not the model's behaviour. Stored with
    ``error_kind`` ``client``, left out and played again like a server's error."""

    kind = "client"


class ServerUnavailable(ConflictbenchError):
    """The policy server cannot be reached at all, even after retrying: the run stops.

    Every finished episode is already stored; the same command resumes once the server is back.
    """

    exit_code = 3

    def __init__(self, url: str, reason: str = ""):
        super().__init__(url, reason)  # both in args, so the error pickles and compares whole
        self.url, self.reason = url, reason

    def __str__(self) -> str:
        why = f" ({self.reason})" if self.reason else ""
        return (
            f"the policy server at {self.url} cannot be reached{why}; check that it is running and "
            f"that the URL is right, then run the same command again to resume"
        )


class StoreFull(ConflictbenchError):
    """The episode store's file system took no more (full, a quota, a file size limit): the run stops with this
    message. The episode being written is not stored and no temporary is left; every episode stored before is whole;
    once space is freed, the same command resumes. ``stored``: how many episodes this run had stored, where known."""

    exit_code = 3

    def __init__(self, root: str, reason: str, stored: int | None = None):
        super().__init__(root, reason, stored)  # all in args, so the error pickles and compares whole
        self.root, self.reason, self.stored = root, reason, stored

    def after(self, stored: int) -> StoreFull:
        """The same error, saying how many episodes the run had stored."""
        return StoreFull(self.root, self.reason, stored)

    def __str__(self) -> str:
        done = "every episode stored before is whole"
        if self.stored is not None:
            done = f"this run stored {self.stored} episode(s) before it, each whole"
        return (
            f"no room left in the episode store {self.root} ({self.reason}); {done}; free space on its disk "
            f"(`conflictbench prune {self.root} --delete` removes superseded episodes) or choose another run.out, "
            "then run the same command again to resume"
        )


class PolicyStalled(ConflictbenchError):
    """A policy call has not returned within its bound (``run.stall_timeout_s``; a thread cannot be stopped):
    the run stops with this message, every finished episode stored; the same command resumes."""

    exit_code = 3


#: What ends a command with its message as one line (``conflictbench: error: ...``) and its ``exit_code``: the
#: command's own handler and a Hydra job's catch exactly these, so a new kind is added here once.
ONE_LINE_ERRORS: tuple[type[ConflictbenchError], ...] = (
    UserError,
    PluginError,
    SimulatorUnavailable,
    ServerUnavailable,
    PolicyStalled,
    StoreFull,
)
