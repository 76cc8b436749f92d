"""What every ``conflictbench-<model> serve`` command shares (model environment side).

    conflictbench-<model> serve --policy P --checkpoint DIR [--host 127.0.0.1] [--port N] [--device cpu]
                                [--max-batch 8] [--threads N]

Every user mistake is one line on stderr and exit code 2, the last line the process writes (the client that
starts the server shows that line as the error): bad numbers, a missing folder or one that is not the
policy's checkpoint (checked before torch is imported, which takes seconds), a Python without the model
stack (the simulator's environment, not the model's), a port that cannot be bound. Once the model is loaded
the port is bound and one line says so; SIGTERM or SIGINT then stop it with exit 0.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .checkpoints import DEVICE, CheckpointError

USER_ERROR = 2


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (exit 2), not its usage block."""

    def error(self, message: str) -> None:
        self.exit(USER_ERROR, f"{self.prog}: {message}\n")


def build_parser(
    program: str,
    description: str,
    policies: list[str],
    protocol: str,
    port: int = 8000,
    checkpoint_help: str = "a LeRobot pretrained-model folder",
) -> Parser:
    """``PROGRAM serve ...`` with the shared options (``port``: the upstream server's usual one)."""
    parser = Parser(prog=program, description=description)
    commands = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    serve = commands.add_parser("serve", help=f"serve a local checkpoint over {protocol}")
    serve.add_argument("--policy", required=True, choices=sorted(policies), help="what the checkpoint holds")
    serve.add_argument("--checkpoint", required=True, type=Path, help=checkpoint_help)
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (default: %(default)s)")
    serve.add_argument("--port", type=int, default=port, help="0: any free port (default: %(default)s)")
    serve.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto (default: %(default)s)")
    serve.add_argument(
        "--max-batch", type=int, default=8,
        help="rows of every forward pass: the requests waiting, padded with copies (default: %(default)s)",
    )  # fmt: skip
    serve.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    return parser


def _stop_quietly(signum: int, frame: object) -> None:
    raise SystemExit(0)


def serve_command(
    program: str,
    environment: str,
    args: argparse.Namespace,
    check: Callable[[Path, str], Any],
    load: Callable[[Path, str], Any],
    serve: Callable[[Any, argparse.Namespace, Callable[[str, int], None]], None],
    url_scheme: str = "ws",
) -> int:
    """Check ``args``, ``check(checkpoint, policy)`` the folder (raise :class:`CheckpointError`), import torch,
    ``load(checkpoint, device)`` the model, and ``serve(model, args, on_ready)`` until stopped. The exit code."""

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
        check(args.checkpoint, args.policy)
    except CheckpointError as error:
        return user_error(str(error))

    # Loading takes seconds to minutes; a stop request meanwhile ends the process quietly as well.
    signal.signal(signal.SIGTERM, _stop_quietly)
    try:
        import torch
    except ImportError as error:
        return user_error(
            f"cannot import the model stack ({error}): run this with the model environment's python "
            f"(scripts/setup.sh --models {environment} builds it), not the simulator's"
        )
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = args.device
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        return user_error(f"--device {args.device}: this machine has no CUDA device torch can use (try --device cpu)")
    try:
        model = load(args.checkpoint, device)
    except CheckpointError as error:
        return user_error(str(error))
    except ImportError as error:
        return user_error(f"cannot import the model stack ({error}): scripts/setup.sh --models {environment} builds it")

    listening = False

    def announce(host: str, port: int) -> None:
        nonlocal listening
        listening = True
        url = f"{url_scheme}://{host}:{port}"
        print(f"{program}: serving {args.policy} from {args.checkpoint} on {url}", file=sys.stderr, flush=True)

    try:
        serve(model, args, announce)
    except (OSError, OverflowError) as error:
        if listening:
            raise
        return user_error(f"cannot listen on {args.host}:{args.port}: {getattr(error, 'strerror', None) or error}")
    return 0


def main(program: str, parser: argparse.ArgumentParser, run: Callable[[argparse.Namespace], int], argv=None) -> int:
    """Parse, set up logging (warnings, the plugin's own INFO lines), run; Ctrl-C while loading: exit 0."""
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format=f"{program}: %(levelname)s %(name)s: %(message)s")
    logging.getLogger(program.replace("-", "_")).setLevel(logging.INFO)
    try:
        return run(args)
    except KeyboardInterrupt:
        return 0
