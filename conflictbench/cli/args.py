"""The argument parser of the verbs that are not Hydra's."""

from __future__ import annotations

import argparse

from conflictbench.core import UserError


class Parser(argparse.ArgumentParser):
    def error(self, message: str):  # a usage mistake is a UserError: one line, exit code 2
        raise UserError(f"{self.prog}: {message}")
