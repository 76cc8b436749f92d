"""A block of README.md that a script writes between two marker lines, and checks (``--check``) in CI.

The scripts that make such a block (readme_design.py, readme_figures.py) import this module from their own
folder: run as ``python scripts/NAME.py``, that folder is on ``sys.path``.
"""

from __future__ import annotations

import difflib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


@dataclass(frozen=True)
class ReadmeBlock:
    script: str
    """The script's name (``readme_design``): its messages' prefix, and what to run to rewrite the block."""
    begin: str
    end: str

    def current(self) -> str:
        """The block in README.md today, markers included; exits naming the markers where it has none."""
        text = README.read_text()
        start, end = text.find(self.begin), text.find(self.end)
        if start < 0 or end < start:
            sys.exit(f"[{self.script}] README.md has no block between {self.begin!r} and {self.end!r}")
        return text[start : end + len(self.end)]

    def write_or_check(self, new: str, check: bool, what: str, same: Callable[[str], str] = str) -> int:
        """Write ``new`` in place of the block, or with ``check`` compare them (as ``same`` reads each: what it
        leaves out may differ) and show the difference: 1 where README's block is not ``new``."""
        old = self.current()
        if check:
            if same(old) != same(new):
                diff = difflib.unified_diff(
                    same(old).splitlines(), same(new).splitlines(), "README.md", "now", lineterm=""
                )
                print("\n".join(diff))
                rerun = f"run scripts/{self.script}.py and commit README.md"
                print(f"[{self.script}] README's {what}: not current; {rerun}", file=sys.stderr)
                return 1
            print(f"[{self.script}] README's {what}: current", file=sys.stderr)
            return 0
        README.write_text(README.read_text().replace(old, new))
        print(f"[{self.script}] README.md: {'unchanged' if new == old else f'its {what} rewritten'}")
        return 0
