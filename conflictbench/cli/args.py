"""The argument parser of the verbs that are not Hydra's."""

from __future__ import annotations

import argparse
from pathlib import Path

from conflictbench.core import UserError


class Parser(argparse.ArgumentParser):
    def error(self, message: str):  # a usage mistake is a UserError: one line, exit code 2
        raise UserError(f"{self.prog}: {message}")


def store_dir(path: str) -> Path:
    """The store directory a command is given (``run.out`` of earlier runs); one line where there is none."""
    root = Path(path)
    if not root.is_dir():
        raise UserError(f"no such directory: {root}")
    return root
