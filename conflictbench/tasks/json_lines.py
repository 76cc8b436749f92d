"""The shipped JSON-lines tables (affordances, review verdicts) read one object a line, with errors that name the
line: the tables are edited by hand, so a mistake is said where it is."""

from __future__ import annotations

import json
from collections.abc import Iterator

from conflictbench.core import UserError


def json_objects(
    text: str, source: str, error: type[UserError], blank_lines: bool = False
) -> Iterator[tuple[int, str, dict]]:
    """(line number, ``"SOURCE line N"``, the object) for each line of ``text``; ``error`` for a line that is not a
    JSON object, and for a blank line unless ``blank_lines`` (then it is passed over)."""
    for number, line in enumerate(text.splitlines(), start=1):
        if blank_lines and not line.strip():
            continue
        where = f"{source} line {number}"
        try:
            row = json.loads(line)
        except json.JSONDecodeError as exc:
            raise error(f"{where}: not valid JSON ({exc.msg})") from None
        if not isinstance(row, dict):
            raise error(f"{where}: expected a JSON object")
        yield number, where, row
