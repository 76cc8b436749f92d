"""A policy server started for one run and stopped at its end (``model.checkpoint=DIR``).

A model plugin whose model lives in its own environment (a separate Python, see the README's "Model
plugins") starts its server with :class:`ServerProcess`: the command runs in its own process group (so
the terminal's Ctrl-C reaches the run, which then stops it), its output goes to a log file, the run waits
until the server's health URL answers 200 (asked directly, never through a proxy; or, for a protocol
without HTTP, until a ``ready`` check the plugin gives returns true), and
:meth:`ServerProcess.stop` ends it: called by the run, at interpreter exit, and, on Linux, by the kernel
when the run's process dies any other way (the server is asked to exit with its parent).

Where the server can say where it listens (``reports_address=True``; ``conflictbench-serve`` can), the run never
names a port: the command gets ``--ready-fd N``, the writing end of a pipe only that process holds, binds any free
port (``--port 0``) once its model is loaded, and writes ``HOST PORT`` there. The run reads the address from its
end of the pipe, so what it then talks to is the port the process it started holds: no other process can take it
first (a port chosen ahead, :func:`free_port`, is free for anyone during the minutes a model loads, and its number
shows on the server's command line) or answer in its name. :attr:`ServerProcess.address` is what it said.

A server that exits during start-up with code 2 reports a user mistake (a checkpoint that is not what
the plugin expects): its last line becomes a :class:`UserError`. Any other early exit, or no answer
within the start-up limit, is :class:`ServerUnavailable` (the run stops, exit code 3), naming the log.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import itertools
import os
import select
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from ..core.errors import ServerUnavailable, UserError

#: Exit code by which a server says the user's input (its checkpoint, its options) is wrong.
USER_ERROR_EXIT_CODE = 2
_PR_SET_PDEATHSIG = 1
_log_numbers = itertools.count()
#: Where a server that reports its address is, in a failure before it said.
_UNREPORTED = "127.0.0.1 (a port the started server had not reported yet)"
#: How long a started server that closed its ready pipe unsaid may take to exit (its exit code says why it stopped:
#: 2 with a one-line user error; a model stack such as torch can take seconds to tear down).
_EXIT_WAIT_S = 15.0
#: Health checks of a local server never go through a proxy (http_proxy would catch 127.0.0.1 too).
_DIRECT = urllib.request.build_opener(urllib.request.ProxyHandler({}))


def _exit_with_parent() -> None:  # runs in the child between fork and exec
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: atexit and the run's own stop() remain
        pass


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port nothing listens on now. Any process may take it before the server does (a model loads for
    minutes): a server the run starts reports the port it bound instead (``ServerProcess(reports_address=True)``)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def answers_health(url: str) -> bool:
    """Whether ``url`` (a server's ``/healthz``) answers 200 now, asked directly (never through a proxy)."""
    try:
        with _DIRECT.open(url, timeout=2) as reply:
            return reply.status == 200
    except (OSError, urllib.error.URLError, ValueError):
        return False


def model_environment(name: str) -> Path:
    """Where ``scripts/setup.sh --models NAME`` puts a model environment: inside the one running us."""
    return Path(sys.prefix) / "models" / name


#: Where a started server logs when not told: a run sets it to ``<run.out>/logs/servers`` (its workers inherit it).
SERVER_LOG_DIR_VARIABLE = "CONFLICTBENCH_SERVER_LOG_DIR"


class ServerProcess:
    """One server process: started, waited for, stopped. Use as a context manager or call start/stop."""

    def __init__(
        self,
        argv: Sequence[str],
        *,
        name: str,
        health_url: str = "",
        ready: Callable[[], bool] | None = None,
        env: Mapping[str, str | None] | None = None,
        startup_timeout_s: float = 600.0,
        log_dir: Path | None = None,
        reports_address: bool = False,
    ):
        self.argv, self.name, self.health_url = list(argv), name, health_url
        self.reports_address = reports_address
        """Whether the command says where it listens over ``--ready-fd N`` (then ``health_url`` and ``ready`` are
        checked after, when given; ``health_url`` may hold ``{port}``)."""
        self.address: tuple[str, int] | None = None
        """``(host, port)`` the started process said it listens on (``reports_address``)."""
        self._ready = ready  # a protocol's own readiness check (a ZeroMQ ping); else GET health_url
        merged = {**os.environ, **(env or {})}
        self.env = {key: value for key, value in merged.items() if value is not None}  # None: left out
        self.startup_timeout_s = startup_timeout_s
        default = os.environ.get(SERVER_LOG_DIR_VARIABLE) or Path(tempfile.gettempdir()) / "conflictbench-servers"
        folder = Path(log_dir) if log_dir is not None else Path(default)
        stamp = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}-{next(_log_numbers)}"
        self.log_path = folder / f"{name}-{stamp}.log"
        self.process: subprocess.Popen | None = None

    def start(self) -> ServerProcess:
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        reading, writing = os.pipe() if self.reports_address else (-1, -1)
        argv = [*self.argv, "--ready-fd", str(writing)] if self.reports_address else self.argv
        try:
            flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC  # never through a link (#42)
            with open(os.open(self.log_path, flags, 0o644), "ab") as log:
                self.process = subprocess.Popen(
                    argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=self.env,
                    start_new_session=True,  # Ctrl-C reaches the run, which then stops the server itself
                    preexec_fn=_exit_with_parent if sys.platform.startswith("linux") else None,
                    pass_fds=(writing,) if self.reports_address else (),  # the same number in the child
                )  # fmt: skip
        except OSError as exc:
            raise UserError(f"could not start the {self.name} server ({self.argv[0]}): {exc}") from None
        finally:
            if self.reports_address:
                os.close(writing)  # the child's copy alone: its exit is the pipe's end
        atexit.register(self.stop)
        deadline = time.monotonic() + self.startup_timeout_s
        try:
            if self.reports_address:
                self.address = self._read_address(reading, deadline)
                self.health_url = self.health_url.format(host=self.address[0], port=self.address[1])
                if not self.health_url and self._ready is None:
                    return self
            while not self._healthy():
                self._check_alive()
                if time.monotonic() > deadline:
                    raise ServerUnavailable(
                        self.health_url,
                        f"the {self.name} server did not answer within {self.startup_timeout_s:g} s "
                        f"(model.startup_timeout_s); its log: {self.log_path}",
                    )
                time.sleep(0.25)
        except BaseException:
            self.stop()
            raise
        finally:
            if self.reports_address:
                os.close(reading)
        return self

    def _check_alive(self) -> None:
        code = self.process.poll()
        if code is not None:
            self._failed_start(code)

    def _read_address(self, reading: int, deadline: float) -> tuple[str, int]:
        """The ``HOST PORT`` line the started process writes on its ready pipe once it listens."""
        said = b""
        while b"\n" not in said:
            self._check_alive()
            left = deadline - time.monotonic()
            if left <= 0:
                raise ServerUnavailable(
                    _UNREPORTED,
                    f"the {self.name} server did not say where it listens within {self.startup_timeout_s:g} s "
                    f"(model.startup_timeout_s); its log: {self.log_path}",
                )
            if not select.select([reading], [], [], min(left, 0.25))[0]:
                continue
            chunk = os.read(reading, 256)
            if not chunk:  # every writer closed it: the process is ending, or will never say
                with contextlib.suppress(subprocess.TimeoutExpired):  # its exit code says why (torch exits slowly)
                    self.process.wait(timeout=min(_EXIT_WAIT_S, max(0.5, deadline - time.monotonic())))
                self._check_alive()
                raise ServerUnavailable(
                    _UNREPORTED,
                    f"the {self.name} server closed its ready pipe without saying where it listens; "
                    f"its log: {self.log_path}",
                )
            said += chunk
            if len(said) > 256:
                break
        host, _, port = said.partition(b"\n")[0].decode(errors="replace").strip().rpartition(" ")
        if not host or not port.isdigit() or not 0 < int(port) < 65536:
            raise ServerUnavailable(
                _UNREPORTED,
                f"the {self.name} server wrote {said[:80]!r} on its ready pipe, not a HOST PORT line; "
                f"its log: {self.log_path}",
            )
        return host, int(port)

    def _healthy(self) -> bool:
        if self._ready is not None:
            try:
                return bool(self._ready())
            except Exception:  # not up yet, whatever the protocol's way of saying so
                return False
        return answers_health(self.health_url)

    def _failed_start(self, code: int) -> None:
        last = self.log_tail(1)
        if code == USER_ERROR_EXIT_CODE and last:
            raise UserError(last)
        raise ServerUnavailable(
            self.health_url if self.address or not self.reports_address else _UNREPORTED,
            f"the {self.name} server exited with code {code} while starting ({last or 'no output'}); "
            f"its log: {self.log_path}",
        )

    def log_tail(self, lines: int = 20) -> str:
        """The last ``lines`` non-empty lines the server wrote."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join([line for line in text.splitlines() if line.strip()][-lines:])

    @property
    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    @property
    def exit_code(self) -> int | None:
        """The server's exit code if it ended on its own (not stopped by :meth:`stop`), else None."""
        return None if self.process is None else self.process.poll()

    def stop(self, grace_s: float = 10.0) -> None:
        """End the server's process group: SIGTERM, then SIGKILL after ``grace_s`` (also if interrupted
        while waiting). Safe to call twice."""
        process = self.process
        if process is None:
            return
        try:
            self._signal_group(process, signal.SIGTERM)
            process.wait(grace_s)
        except (subprocess.TimeoutExpired, KeyboardInterrupt):
            pass
        finally:
            self._signal_group(process, signal.SIGKILL)  # the group: a server's own children go too
            try:
                process.wait(5.0)
            except subprocess.TimeoutExpired:
                pass
            self.process = None
            atexit.unregister(self.stop)

    @staticmethod
    def _signal_group(process: subprocess.Popen, sig: int) -> None:
        try:
            os.killpg(process.pid, sig)  # the group outlives its leader; its id stays the leader's pid
        except (ProcessLookupError, PermissionError):
            pass

    def __enter__(self) -> ServerProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
