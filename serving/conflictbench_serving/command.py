"""``conflictbench-serve``: host a local checkpoint of any installed model plugin (model environment side).

    conflictbench-serve POLICY --checkpoint DIR [--host 127.0.0.1] [--port N] [--device cpu] [--max-batch 8]
                        [--threads N] [--token-file PATH] [--max-message-mib M] [--max-connections N]
    conflictbench-serve --list

A plugin declares what it serves with a :class:`ServedModel` under the entry-point group ``conflictbench_serving``
(``pi0 = "conflictbench_pi0.server:SERVED"``); the command finds it there, so one command serves every model and a
plugin's own ``conflictbench-<name> serve --policy POLICY ...`` is the same code under its old name
(:func:`plugin_main`, its console script and ``python -m conflictbench_<name> serve``; deprecated, they warn). A
run with ``model.checkpoint=DIR`` starts ``python -m conflictbench_serving POLICY ...``.

Every user mistake is one line on stderr and exit code 2, the last line the process writes (the client that
starts the server shows that line as the error): a policy no installed plugin serves, bad numbers, a missing
folder or one that is not the policy's checkpoint (checked before torch is imported, which takes seconds), a
Python without the model stack (the simulator's environment, not the model's), a port that cannot be bound. Once
the model is loaded the port is bound and one line says so; SIGTERM or SIGINT then stop it with exit 0.

Who may use it (README, "Security"): with a token, every request must carry it (openpi-client's ``Authorization:
Api-Key TOKEN`` header on websocket and REST, the ``api_token`` field on ZeroMQ); without one, anyone who reaches
the port may. The token comes from the environment variable ``CONFLICTBENCH_SERVER_TOKEN`` or from a file
(``--token-file``), never from the command line, which ``ps`` shows every user; it is never printed. A token does
not encrypt: reach a server on another machine through an SSH tunnel or a private network. ``--max-message-mib`` and
``--max-connections`` bound what one peer can make the server read or hold (:mod:`.guard`).

``--ready-fd N`` is how a run that starts the server learns where it listens: with ``--port 0`` the server binds
any free port and, once it listens, writes ``HOST PORT`` and a newline to that inherited file descriptor.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import os
import signal
import stat
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from . import guard
from .checkpoints import DEVICE, CheckpointError
from .stack import installed_versions, model_stack

USER_ERROR = 2
_LOOPBACK = ("127.0.0.1", "localhost", "::1")
PROGRAM = "conflictbench-serve"
ENTRY_POINT_GROUP = "conflictbench_serving"


@dataclass(frozen=True)
class ServedModel:
    """What a plugin's models need to be served: declared once, found through the entry point."""

    environment: str
    """The plugin's model environment (``scripts/setup.sh --models NAME`` builds it)."""
    policies: tuple[str, ...]
    """The policy names it hosts (the command's ``POLICY``)."""
    protocol: str
    """The wire protocol, in words (for ``--help`` and ``--list``)."""
    check: Callable[[Path, str, str], object]
    """``check(folder, policy, naming)``: raise :class:`CheckpointError` unless the folder holds a checkpoint of
    ``policy``; ``naming`` is how this command names a policy (``--policy ``), for a message that says which to
    use. Called before torch is imported."""
    backend: str | Callable[..., Any]
    """``backend(checkpoint, device=...)`` loads the model (``"module:function"``, imported after the checks)."""
    server: str | Callable[..., None]
    """``server(backend, host, port, max_batch, on_ready=...)`` serves it until stopped (``"module:function"``)."""
    port: int = 8000
    """The port upstream's server listens on by default."""
    url_scheme: str = "ws"
    checkpoint_help: str = "a LeRobot pretrained-model folder"

    @classmethod
    def of(cls, package: str, **fields: Any) -> ServedModel:
        """A plugin package's, laid out as every model plugin is: ``package.backend.load_backend``,
        ``package.server.serve``, and the model environment named after it (``conflictbench_NAME``: ``NAME``)."""
        defaults = {
            "environment": package.removeprefix("conflictbench_"),
            "backend": f"{package}.backend:load_backend",
            "server": f"{package}.server:serve",
        }
        return cls(**{**defaults, **fields})


def _resolve(target: str | Callable[..., Any]) -> Callable[..., Any]:
    if callable(target):
        return target
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def served_models() -> tuple[dict[str, ServedModel], dict[str, str]]:
    """Every installed plugin's :class:`ServedModel` by the policy names it hosts, and the entry points that
    failed to load (name: why)."""
    models: dict[str, ServedModel] = {}
    failures: dict[str, str] = {}
    for entry in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            model = entry.load()
        except Exception as error:  # a broken plugin must not hide the others
            failures[entry.name] = f"{type(error).__name__}: {error}"
            continue
        models.update({policy: model for policy in model.policies})
    return models, failures


def served_model(policy: str) -> ServedModel:
    """The installed :class:`ServedModel` that hosts ``policy``; :class:`LookupError` (one line) if none does."""
    models, failures = served_models()
    if policy in models:
        return models[policy]
    broken = (
        f"; plugins that failed to load: {', '.join(f'{k} ({v})' for k, v in failures.items())}" if failures else ""
    )
    # A plugin's client half (beside the simulator) declares nothing here: its server half is in its model environment.
    where = "" if models else "; a model plugin's server half is in its model environment: run its conflictbench-serve"
    raise LookupError(
        f"no installed plugin serves {policy!r} (installed: {', '.join(sorted(models)) or 'none'}{where}){broken}"
    )


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2), not its usage block, and no abbreviations: ``--token VALUE`` would
    otherwise be read as ``--token-file VALUE`` and a secret typed there named in an error."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, allow_abbrev=False, **kwargs)

    def error(self, message: str) -> None:
        self.exit(USER_ERROR, f"{self.prog}: {message}\n")


def _add_options(parser: argparse.ArgumentParser, port: int | None, checkpoint_help: str) -> None:
    parser.add_argument("--checkpoint", required=True, type=Path, help=checkpoint_help)
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default: %(default)s)")
    port_help = "0: any free port (default: %(default)s)" if port else "0: any free port (default: the model's own)"
    parser.add_argument("--port", type=int, default=port, help=port_help)
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto (default: %(default)s)")
    parser.add_argument(
        "--max-batch", type=int, default=8,
        help="rows of every forward pass: the requests waiting, padded with copies (default: %(default)s)",
    )  # fmt: skip
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument(
        "--token-file", type=Path, default=None, metavar="PATH",
        help=f"a file holding the token every request must carry (default: ${guard.TOKEN_VARIABLE}, else none)",
    )  # fmt: skip
    parser.add_argument(
        "--max-message-mib", type=float, default=None, metavar="M",
        help=f"largest request read, in MiB (default: {guard.DEFAULT_MAX_MESSAGE_BYTES / 2**20:g})",
    )  # fmt: skip
    parser.add_argument(
        "--max-connections", type=int, default=None, metavar="N",
        help=f"connections served at once, at least the run's workers (default: {guard.DEFAULT_MAX_CONNECTIONS})",
    )  # fmt: skip
    parser.add_argument(
        "--ready-fd", type=int, default=None, metavar="N",
        help="once listening, write 'HOST PORT' to this inherited file descriptor (how a run learns the port)",
    )  # fmt: skip


def build_parser() -> Parser:
    """``conflictbench-serve POLICY --checkpoint DIR ...`` (``--list``: what the installed plugins serve)."""
    parser = Parser(prog=PROGRAM, description="Host a local checkpoint of any installed conflictbench model plugin.")
    parser.add_argument("policy", nargs="?", help="the policy the checkpoint holds (--list shows them)")
    parser.add_argument("--list", action="store_true", help="list what the installed plugins serve, and exit")
    _add_options(parser, None, "the checkpoint folder")
    return parser


def build_plugin_parser(program: str, model: ServedModel) -> Parser:
    """A plugin's own ``PROGRAM serve --policy P ...``: the same options under the name it has always had."""
    parser = Parser(prog=program, description=f"{', '.join(model.policies)} for conflictbench, model-environment side.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    serve = commands.add_parser("serve", help=f"serve a local checkpoint over {model.protocol}")
    serve.add_argument("--policy", required=True, choices=sorted(model.policies), help="what the checkpoint holds")
    _add_options(serve, model.port, model.checkpoint_help)
    return parser


def _stop_quietly(signum: int, frame: object) -> None:
    raise SystemExit(0)


def _simulators_python() -> bool:
    """Whether this Python is the simulator's: it holds conflictbench, which a model environment never does."""
    return importlib.util.find_spec("conflictbench") is not None


def _missing_stack(model: ServedModel, error: ImportError) -> str:
    """The one line for a model stack that does not import: where torch is what is missing, or this Python is the
    simulator's, it is the wrong Python; else the model environment lacks a package."""
    wrong_python = _simulators_python() or (error.name or "").partition(".")[0] == "torch"
    build = f"scripts/setup.sh --models {model.environment} builds it"
    where = f"run this with the model environment's python ({build}), not the simulator's" if wrong_python else build
    return f"cannot import the model stack ({error}): {where}"


def serve_command(program: str, model: ServedModel, args: argparse.Namespace, naming: str = "--policy ") -> int:
    """Check ``args`` and the folder (``model.check``), import torch, load the model and serve it until stopped.
    The exit code."""

    def user_error(message: str) -> int:
        print(f"{program}: {message}", file=sys.stderr, flush=True)
        return USER_ERROR

    if args.max_batch < 1:
        return user_error(f"--max-batch must be at least 1, got {args.max_batch}")
    if not DEVICE.fullmatch(args.device):
        return user_error(f"--device must be cpu, cuda, cuda:N or auto, got {args.device!r}")
    if args.threads is not None and args.threads < 1:
        return user_error(f"--threads must be at least 1, got {args.threads}")
    try:
        ready = _ready_pipe(args.ready_fd)
        _configure_guard(args)
    except ValueError as error:
        return user_error(str(error))
    try:
        model.check(args.checkpoint, args.policy, naming)
    except CheckpointError as error:
        return user_error(str(error))

    # Loading takes seconds to minutes; a stop request meanwhile ends the process quietly as well.
    signal.signal(signal.SIGTERM, _stop_quietly)
    try:
        import torch
    except ImportError as error:
        if _simulators_python():  # it never hosts a model, so its error comes before the backend's own checks
            return user_error(_missing_stack(model, error))
        torch = None  # a backend of numpy alone is served without it; one that needs it says so as it loads
    if args.threads is not None and torch is not None:
        torch.set_num_threads(args.threads)
    cuda = torch is not None and torch.cuda.is_available()
    device = args.device
    if device == "auto":
        device = "cuda" if cuda else "cpu"
    if device.startswith("cuda") and torch is None:
        return user_error(_missing_stack(model, ModuleNotFoundError("No module named 'torch'", name="torch")))
    if device.startswith("cuda") and not cuda:
        return user_error(f"--device {args.device}: this machine has no CUDA device torch can use (try --device cpu)")
    try:
        backend = _resolve(model.backend)(args.checkpoint, device=device)
        # What a run given this server's address counts in its episodes' identity (a checkpoint run reads the same
        # from the model environment's files before it starts the server).
        if isinstance(getattr(backend, "metadata", None), dict):
            backend.metadata = {**backend.metadata, "model_stack": model_stack(device, installed_versions())}
    except CheckpointError as error:
        return user_error(str(error))
    except ImportError as error:
        return user_error(_missing_stack(model, error))

    listening = False

    def announce(host: str, port: int) -> None:
        nonlocal listening
        listening = True
        url = f"{model.url_scheme}://{host}:{port}"
        print(f"{program}: serving {args.policy} from {args.checkpoint} on {url}", file=sys.stderr, flush=True)
        if guard.current().token is None and host not in _LOOPBACK:
            print(
                f"{program}: warning: no token: anyone who reaches {host}:{port} may use this model (set "
                f"{guard.TOKEN_VARIABLE} or --token-file; README, Security)",
                file=sys.stderr,
                flush=True,
            )
        if ready is not None:  # after the line above: the run that reads it may stop us at once
            with ready:
                ready.write(f"{host} {port}\n".encode())

    try:
        _resolve(model.server)(backend, args.host, args.port, args.max_batch, on_ready=announce)
    except (OSError, OverflowError) as error:
        if listening:
            raise
        return user_error(f"cannot listen on {args.host}:{args.port}: {getattr(error, 'strerror', None) or error}")
    return 0


def _ready_pipe(fd: int | None):
    """The file ``--ready-fd`` names, opened for writing (None without it); ValueError (one line) if it is not open.
    Not passed on to the model's own processes: the run must see it close when this process ends."""
    if fd is None:
        return None
    try:
        if fd < 3 or not stat.S_ISFIFO(os.fstat(fd).st_mode) and not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError("not a pipe or a file")
        os.set_inheritable(fd, False)
        return open(fd, "wb", buffering=0)  # noqa: SIM115 (closed once the address is written)
    except OSError as error:
        raise ValueError(f"--ready-fd {fd}: no open pipe there ({getattr(error, 'strerror', None) or error})") from None


def _read_token(args: argparse.Namespace) -> str | None:
    """The token from ``--token-file`` or the environment (taken out of it: the model's own code and the processes
    it starts need not see it); None for none. ValueError (one line, never the token) for an unusable one."""
    from_environment = os.environ.pop(guard.TOKEN_VARIABLE, None) or None
    if args.token_file is None:
        return from_environment
    try:
        token = args.token_file.read_text().strip()
        mode = args.token_file.stat().st_mode
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"--token-file {args.token_file}: cannot read it ({type(error).__name__})") from None
    if not token or any(character.isspace() for character in token):
        raise ValueError(f"--token-file {args.token_file}: the token must be one word, on one line, not empty")
    if mode & (stat.S_IRGRP | stat.S_IROTH):
        print(
            f"{PROGRAM}: warning: --token-file {args.token_file} is readable by other users (chmod 600 it)",
            file=sys.stderr,
            flush=True,
        )
    return token


def _configure_guard(args: argparse.Namespace) -> None:
    """The process-wide guard every server of ours uses, from the options and the environment."""
    changes: dict[str, Any] = {"token": _read_token(args)}
    if args.max_message_mib is not None:
        if not args.max_message_mib > 0:
            raise ValueError(f"--max-message-mib must be more than 0, got {args.max_message_mib:g}")
        changes["max_message_bytes"] = max(1, int(args.max_message_mib * 2**20))
    if args.max_connections is not None:
        if args.max_connections < 1:
            raise ValueError(f"--max-connections must be at least 1, got {args.max_connections}")
        changes["max_connections"] = args.max_connections
    if changes["token"] is not None and any(character.isspace() for character in changes["token"]):
        raise ValueError(f"${guard.TOKEN_VARIABLE}: the token must be one word, without spaces")
    guard.configure(**changes)


def _run(program: str, model: ServedModel, run: Callable[[], int]) -> int:
    """Set up logging (warnings, the plugin's own INFO lines) and run; Ctrl-C while loading: exit 0."""
    logging.basicConfig(level=logging.WARNING, format=f"{program}: %(levelname)s %(name)s: %(message)s")
    if isinstance(model.backend, str):  # the plugin's package: its loggers are named after its modules
        logging.getLogger(model.backend.partition(".")[0]).setLevel(logging.INFO)
    try:
        return run()
    except KeyboardInterrupt:
        return 0


def _listing() -> int:
    models, failures = served_models()
    for policy, model in sorted(models.items()):
        print(f"{policy:<14} {model.environment:<10} {model.protocol}")
    for name, why in failures.items():
        print(f"{PROGRAM}: the plugin {name} failed to load: {why}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    """``conflictbench-serve``."""
    if argv is None:
        argv = sys.argv[1:]
    if "--list" in argv:
        return _listing()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.policy is None:
        parser.error("the following arguments are required: POLICY (--list shows them)")
    try:
        model = served_model(args.policy)
    except LookupError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return USER_ERROR
    if args.port is None:
        args.port = model.port
    return _run(PROGRAM, model, lambda: serve_command(PROGRAM, model, args, naming=f"{PROGRAM} "))


def plugin_main(program: str | None = None, argv: list[str] | None = None) -> int:
    """A plugin's own command, ``conflictbench-NAME serve --policy P ...`` (kept beside ``conflictbench-serve P``):
    the plugin whose ``conflictbench_serving`` entry point is ``NAME`` (``-`` for ``_``), by the program's name.

    Deprecated with the console scripts and ``python -m conflictbench_NAME`` that call it: it warns, blaming its
    caller (their ``__main__``, so Python shows it), and goes in conflictbench 0.4.0 (conflictbench-serving 0.3.0)."""
    program = program or Path(sys.argv[0]).name
    warnings.warn(
        f"{program} serve --policy POLICY is deprecated and goes in conflictbench 0.4.0 (conflictbench-serving "
        f"0.3.0): use {PROGRAM} POLICY with the same options (python -m conflictbench_serving POLICY)",
        DeprecationWarning,
        stacklevel=2,
    )
    name = program.removeprefix("conflictbench-").replace("-", "_")
    found = [entry for entry in metadata.entry_points(group=ENTRY_POINT_GROUP) if entry.name == name]
    if not found:
        print(f"{program}: no installed plugin declares {name!r} in the {ENTRY_POINT_GROUP} group", file=sys.stderr)
        return USER_ERROR
    model = found[0].load()
    args = build_plugin_parser(program, model).parse_args(argv)
    return _run(program, model, lambda: serve_command(program, model, args))
