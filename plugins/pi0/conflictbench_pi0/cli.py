"""``conflictbench-pi0 serve``: host a LeRobot π checkpoint over openpi's protocol (model environment).

    conflictbench-pi0 serve --policy {pi0,pi05,pi0-fast} --checkpoint DIR [--host 127.0.0.1] [--port 8000]
                            [--device cpu] [--max-batch 8] [--threads N]

The checks, messages and exit codes are conflictbench-serving's (:mod:`conflictbench_serving.command`):
every user mistake is one line on stderr and exit code 2, checked before torch is imported.
"""

from __future__ import annotations

import argparse
import sys

from conflictbench_pi0.checkpoints import POLICY_TYPES, check_checkpoint
from conflictbench_serving import command

PROGRAM = "conflictbench-pi0"


def build_parser() -> argparse.ArgumentParser:
    description = "π0, π0-FAST and π0.5 for conflictbench, model-environment side."
    return command.build_parser(PROGRAM, description, list(POLICY_TYPES), "openpi's websocket protocol")


def _load(checkpoint, device: str):
    from conflictbench_pi0.backend import load_backend

    return load_backend(checkpoint, device=device)


def _serve(backend, args: argparse.Namespace, on_ready) -> None:
    from conflictbench_pi0.server import serve

    serve(backend, args.host, args.port, args.max_batch, on_ready=on_ready)


def serve_command(args: argparse.Namespace) -> int:
    def check(checkpoint, policy: str) -> None:
        check_checkpoint(checkpoint, policy, option="--policy ")

    return command.serve_command(PROGRAM, "pi0", args, check, _load, _serve)


def main(argv: list[str] | None = None) -> int:
    return command.main(PROGRAM, build_parser(), serve_command, argv)


if __name__ == "__main__":
    sys.exit(main())
