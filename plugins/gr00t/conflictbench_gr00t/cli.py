"""``conflictbench-gr00t serve``: host a LeRobot GR00T N1.7 checkpoint over NVIDIA's ZeroMQ protocol.

    conflictbench-gr00t serve --policy gr00t --checkpoint DIR [--host 127.0.0.1] [--port 5555]
                              [--device cpu] [--max-batch 8] [--threads N]

Run it with the model environment's python (``scripts/setup.sh --models gr00t``). The checks, messages and exit
codes are conflictbench-serving's (:mod:`conflictbench_serving.command`).
"""

from __future__ import annotations

import argparse
import sys

from conflictbench_serving import command

from .checkpoints import check_checkpoint

PROGRAM = "conflictbench-gr00t"


def _load(checkpoint, device: str):
    from .backend import load_backend

    return load_backend(checkpoint, device=device)


def _serve(backend, args: argparse.Namespace, on_ready) -> None:
    from .server import serve

    serve(backend, args.host, args.port, args.max_batch, on_ready=on_ready)


def serve_command(args: argparse.Namespace) -> int:
    return command.serve_command(
        PROGRAM, "gr00t", args, lambda folder, _: check_checkpoint(folder), _load, _serve, url_scheme="tcp"
    )


def main(argv: list[str] | None = None) -> int:
    parser = command.build_parser(
        PROGRAM, "GR00T N1.7 for conflictbench, model-environment side.", ["gr00t"], "NVIDIA's ZeroMQ protocol", 5555
    )
    return command.main(PROGRAM, parser, serve_command, argv)


if __name__ == "__main__":
    sys.exit(main())
