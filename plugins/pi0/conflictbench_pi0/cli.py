"""``conflictbench-pi0 serve``: host a LeRobot π checkpoint over openpi's protocol (model environment).

    conflictbench-pi0 serve --policy {pi0,pi05,pi0-fast} --checkpoint DIR [--host 127.0.0.1] [--port 8000]
                            [--device cpu] [--max-batch 8] [--threads N]

Every user mistake is one line on stderr and exit code 2, the last line the process writes (the
client that starts this server shows that line as the error): a missing folder, one that is not a π
checkpoint or holds another policy than ``--policy`` (checked before torch is imported, which takes
seconds), and a Python without lerobot/torch (the simulator's environment, not the model's). Once the
model is loaded the port is bound and one line says so; SIGTERM or SIGINT then stop it with exit 0.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path

from conflictbench_pi0.checkpoints import DEVICE, POLICY_TYPES, CheckpointError, checkpoint_type

PROGRAM = "conflictbench-pi0"
USER_ERROR = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, not argparse's usage block
        self.exit(USER_ERROR, f"{self.prog}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROGRAM, description="π0, π0-FAST and π0.5 for conflictbench, model-environment side.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    serve = commands.add_parser("serve", help="serve a LeRobot checkpoint over openpi's websocket protocol")
    serve.add_argument("--policy", required=True, choices=sorted(POLICY_TYPES), help="what the checkpoint holds")
    serve.add_argument("--checkpoint", required=True, type=Path, help="a LeRobot pretrained-model folder")
    serve.add_argument("--host", default="127.0.0.1", help="address to listen on (default: %(default)s)")
    serve.add_argument("--port", type=int, default=8000, help="0: any free port (default: %(default)s)")
    serve.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto (default: %(default)s)")
    serve.add_argument(
        "--max-batch", type=int, default=8,
        help="rows of every forward pass: the requests waiting, padded with copies (default: %(default)s)",
    )  # fmt: skip
    serve.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    return parser


def _user_error(message: str) -> int:
    print(f"{PROGRAM}: {message}", file=sys.stderr, flush=True)
    return USER_ERROR


def _stop_quietly(signum: int, frame: object) -> None:
    raise SystemExit(0)


def serve_command(args: argparse.Namespace) -> int:
    if args.max_batch < 1:
        return _user_error(f"--max-batch must be at least 1, got {args.max_batch}")
    if not DEVICE.fullmatch(args.device):
        return _user_error(f"--device must be cpu, cuda, cuda:N or auto, got {args.device!r}")
    if args.threads is not None and args.threads < 1:
        return _user_error(f"--threads must be at least 1, got {args.threads}")
    try:
        found = checkpoint_type(args.checkpoint)
    except CheckpointError as error:
        return _user_error(str(error))
    if found != POLICY_TYPES[args.policy]:
        named = next(name for name, kind in POLICY_TYPES.items() if kind == found)
        return _user_error(f"{args.checkpoint} is a {found} checkpoint: use --policy {named}, not {args.policy}")

    # Loading takes seconds to minutes; a stop request meanwhile ends the process quietly as well.
    signal.signal(signal.SIGTERM, _stop_quietly)
    try:
        import torch

        from conflictbench_pi0.backend import load_backend
        from conflictbench_pi0.server import serve
    except ImportError as error:
        return _user_error(
            f"cannot import the model stack ({error}): run this with the model environment's python "
            "(scripts/setup.sh --models pi0 builds it), not the simulator's"
        )
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = args.device
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        return _user_error(f"--device {args.device}: this machine has no CUDA device torch can use (try --device cpu)")
    try:
        backend = load_backend(args.checkpoint, device=device)
    except CheckpointError as error:
        return _user_error(str(error))

    listening = False

    def announce(host: str, port: int) -> None:
        nonlocal listening
        listening = True
        url = f"ws://{host}:{port}"
        print(f"{PROGRAM}: serving {args.policy} from {args.checkpoint} on {url}", file=sys.stderr, flush=True)

    try:
        serve(backend, args.host, args.port, args.max_batch, on_ready=announce)
    except (OSError, OverflowError) as error:
        if listening:
            raise
        return _user_error(f"cannot listen on {args.host}:{args.port}: {getattr(error, 'strerror', None) or error}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format=f"{PROGRAM}: %(levelname)s %(name)s: %(message)s")
    logging.getLogger("conflictbench_pi0").setLevel(logging.INFO)
    try:
        return serve_command(args)
    except KeyboardInterrupt:  # Ctrl-C while loading
        return 0


if __name__ == "__main__":
    sys.exit(main())
