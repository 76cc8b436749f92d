"""What a run trusts of a policy server, and why: the token its requests carry, and the server it started.

- **The token.** A server the run starts gets a fresh one in its environment (``CONFLICTBENCH_SERVER_TOKEN``, never
  its command line, which ``ps`` shows every user); a running server's (``model.server``) is read from
  ``model.token_file`` or that variable, here, never from the run's config, so neither Hydra's saved config nor the
  results nor the logs hold it. The protocol's transport sends it on every request (``token=``, or ZeroMQ's
  ``api_token=``). It keeps other users of the network or the machine from using the server; it encrypts nothing.
- **The server it started.** Once that process has exited its port is anyone's: a connection to it refuses then
  (:class:`StartedServerConnection`), so a request is never sent to whoever binds the port next.
"""

from __future__ import annotations

import inspect
import os
import stat
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..core.errors import UserError
from .launch import ServerProcess
from .transport import Transport

#: Where a run and a server read their shared token from (conflictbench_serving.guard's name for it, restated: a
#: test keeps the two equal).
TOKEN_VARIABLE = "CONFLICTBENCH_SERVER_TOKEN"


def configured_token(token_file: str = "") -> str | None:
    """The token of a running server: ``token_file``'s (``model.token_file``), else ``$CONFLICTBENCH_SERVER_TOKEN``,
    else None. A file that cannot be read, or holds no single word, is one line (:class:`UserError`), never the
    token; one that other users can read is warned of. The rules of ``conflictbench-serve --token-file``
    (``conflictbench_serving.command``), restated: the two live in different distributions, and conflictbench's
    own install needs no conflictbench-serving."""
    if not token_file:
        return os.environ.get(TOKEN_VARIABLE) or None
    path = Path(token_file).expanduser()
    try:
        token = path.read_text().strip()
        mode = path.stat().st_mode
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"model.token_file={token_file}: cannot read it ({type(exc).__name__})") from None
    if not token or any(character.isspace() for character in token):
        raise UserError(f"model.token_file={token_file}: the token must be one word, on one line")
    if mode & (stat.S_IRGRP | stat.S_IROTH):
        print(
            f"conflictbench: warning: model.token_file={token_file} is readable by other users (chmod 600 it)",
            file=sys.stderr,
        )
    return token


def token_argument(transport: Callable[..., Transport]) -> str | None:
    """The argument by which ``transport`` takes a token (``token``, or ZeroMQ's ``api_token``); None: none."""
    try:
        parameters = inspect.signature(transport).parameters
    except (TypeError, ValueError):
        return None
    return next((name for name in ("token", "api_token") if name in parameters), None)


class StartedServerConnection(Transport):
    """A transport to a server this run started: refuses to connect or send once that process has exited (its port
    is then anyone's); else the protocol's own transport, whose ``metadata`` and other attributes it shows."""

    def __init__(self, inner: Transport, server: ServerProcess):
        super().__init__(inner.url)
        self._inner, self._server = inner, server

    def _check(self) -> None:
        if not self._server.running:
            raise ConnectionRefusedError(f"the server started for this run has exited ({self._server.exit_code})")

    def connect(self, timeout: float) -> None:
        self._check()
        self._inner.connect(timeout)

    def exchange(self, request: Any, timeout: float) -> Any:
        self._check()
        return self._inner.exchange(request, timeout)

    def close(self) -> None:
        self._inner.close()

    def __getattr__(self, name: str) -> Any:  # metadata, and whatever else a plugin reads from its transport
        return getattr(self._inner, name)
