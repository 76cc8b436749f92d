"""``conflictbench-univla serve``: host a UniVLA checkpoint (UniVLA's code from ``UNIVLA_CODE``) over REST.

    UNIVLA_CODE=/path/to/UniVLA conflictbench-univla serve --policy univla --checkpoint DIR [--host 127.0.0.1]
                                [--port 8000] [--device cpu] [--max-batch 8] [--threads N]

Run it with the model environment's python (``scripts/setup.sh --models univla``). The checks, messages and exit
codes are conflictbench-serving's (:mod:`conflictbench_serving.command`).
"""

from __future__ import annotations

import argparse
import sys

from conflictbench_serving import command

from .checkpoints import check_checkpoint, check_code

PROGRAM = "conflictbench-univla"


def _check(folder, policy: str):
    check_code()
    return check_checkpoint(folder)


def _load(checkpoint, device: str):
    from .backend import load_backend

    return load_backend(checkpoint, device=device)


def _serve(backend, args: argparse.Namespace, on_ready) -> None:
    from .server import serve

    serve(backend, args.host, args.port, args.max_batch, on_ready=on_ready)


def serve_command(args: argparse.Namespace) -> int:
    return command.serve_command(PROGRAM, "univla", args, _check, _load, _serve, url_scheme="http")


def main(argv: list[str] | None = None) -> int:
    parser = command.build_parser(
        PROGRAM, "UniVLA for conflictbench, model-environment side.", ["univla"], "our REST protocol (json-numpy)",
        8000, checkpoint_help="a UniVLA checkpoint folder: the VLA in Hugging Face format and action_decoder.pt",
    )  # fmt: skip
    return command.main(PROGRAM, parser, serve_command, argv)


if __name__ == "__main__":
    sys.exit(main())
