"""``conflictbench-vla-jepa serve``: host a LeRobot VLA-JEPA checkpoint over starVLA's websocket protocol.

    conflictbench-vla-jepa serve --policy vla-jepa --checkpoint DIR [--host 127.0.0.1] [--port 8000]
                                 [--device cpu] [--max-batch 8] [--threads N]

Run it with the model environment's python (``scripts/setup.sh --models vla_jepa``). The checks, messages and
exit codes are conflictbench-serving's (:mod:`conflictbench_serving.command`).
"""

from __future__ import annotations

import argparse
import sys

from conflictbench_serving import command

from .checkpoints import check_checkpoint

PROGRAM = "conflictbench-vla-jepa"


def _load(checkpoint, device: str):
    from .backend import load_backend

    return load_backend(checkpoint, device=device)


def _serve(backend, args: argparse.Namespace, on_ready) -> None:
    from .server import serve

    serve(backend, args.host, args.port, args.max_batch, on_ready=on_ready)


def serve_command(args: argparse.Namespace) -> int:
    return command.serve_command(PROGRAM, "vla_jepa", args, lambda folder, _: check_checkpoint(folder), _load, _serve)


def main(argv: list[str] | None = None) -> int:
    parser = command.build_parser(
        PROGRAM, "VLA-JEPA for conflictbench, model-environment side.", ["vla-jepa"], "VLA-JEPA's websocket protocol"
    )
    return command.main(PROGRAM, parser, serve_command, argv)


if __name__ == "__main__":
    sys.exit(main())
