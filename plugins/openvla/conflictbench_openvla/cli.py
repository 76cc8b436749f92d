"""``conflictbench-openvla serve``: host an OpenVLA checkpoint over ``deploy.py``'s REST protocol.

    conflictbench-openvla serve --policy openvla --checkpoint DIR [--host 127.0.0.1] [--port 8000]
                                [--device cpu] [--max-batch 8] [--threads N]

Run it with the model environment's python (``scripts/setup.sh --models openvla``). The checks, messages and exit
codes are conflictbench-serving's (:mod:`conflictbench_serving.command`).
"""

from __future__ import annotations

import argparse
import sys

from conflictbench_serving import command

from .checkpoints import check_checkpoint

PROGRAM = "conflictbench-openvla"


def _load(checkpoint, device: str):
    from .backend import load_backend

    return load_backend(checkpoint, device=device)


def _serve(backend, args: argparse.Namespace, on_ready) -> None:
    from .server import serve

    serve(backend, args.host, args.port, args.max_batch, on_ready=on_ready)


def serve_command(args: argparse.Namespace) -> int:
    return command.serve_command(PROGRAM, "openvla", args, check_checkpoint, _load, _serve, url_scheme="http")


def main(argv: list[str] | None = None) -> int:
    parser = command.build_parser(
        PROGRAM, "OpenVLA for conflictbench, model-environment side.", ["openvla", "openvla-oft"],
        "deploy.py's REST protocol (json-numpy)", 8000,
        checkpoint_help="an OpenVLA checkpoint folder in Hugging Face format (with its own model code)",
    )  # fmt: skip
    return command.main(PROGRAM, parser, serve_command, argv)


if __name__ == "__main__":
    sys.exit(main())
