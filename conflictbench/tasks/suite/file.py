"""The conflict-suite file: JSON Lines, a header line then one case per line.

Header (line 1)::

    {"format": "conflictbench-suite", "format_version": 1, "name": ..., "version": ...,
     "cases": N, "sha256": <hex digest of every case line, each followed by "\\n">}

Each further line is one :class:`ConflictCase` as a JSON object (``case_id, suite, task_id,
base_instruction, instruction, family, level, factors, premise, witness, status, init_states``).
The shipped suite must carry the header and a matching checksum; an exported file (``suite
export``) may be headerless.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from conflictbench.core import FAMILIES, LEVELS, LIBERO_SUITES, ConflictCase, UserError

FORMAT = "conflictbench-suite"
FORMAT_VERSION = 1
STATUSES = ("accepted", "revised", "removed", "pending")
USABLE = ("accepted", "revised")
"""Statuses of cases a run may play: validated, and accepted or revised in review."""
SHIPPED = "suite.jsonl"


class SuiteFormatError(UserError):
    pass


@dataclass(frozen=True)
class Suite:
    name: str
    version: str
    cases: tuple[ConflictCase, ...]
    path: str = ""

    @property
    def label(self) -> str:
        """``name version`` (a file without a header: its name), as stored with each of its conflict episodes."""
        return f"{self.name} {self.version}".strip()

    def accepted(self) -> list[ConflictCase]:
        """The usable cases: accepted, or revised in review (removed and pending ones are not)."""
        return [c for c in self.cases if c.status in USABLE]


_REQUIRED: dict[str, type | tuple[type, ...]] = {
    "case_id": str,
    "suite": str,
    "task_id": int,
    "base_instruction": str,
    "instruction": str,
    "family": str,
    "level": str,
}
_OPTIONAL: dict[str, Any] = {
    "factors": (list, []),
    "premise": (str, ""),
    "witness": (dict, {}),
    "status": (str, "accepted"),
    "init_states": ((list, type(None)), None),
}


def _case_from(obj: Any, where: str, families: tuple[str, ...] = FAMILIES) -> ConflictCase:
    if not isinstance(obj, dict):
        raise SuiteFormatError(f"{where}: expected a JSON object, got {type(obj).__name__}")
    for name, kind in _REQUIRED.items():
        if name not in obj:
            raise SuiteFormatError(f"{where}, field {name!r}: missing")
        if not isinstance(obj[name], kind) or isinstance(obj[name], bool):
            raise SuiteFormatError(f"{where}, field {name!r}: expected {kind.__name__}, got {obj[name]!r}")
    values = {name: obj[name] for name in _REQUIRED}
    for name, (kind, default) in _OPTIONAL.items():
        value = obj.get(name, default)
        if not isinstance(value, kind):
            raise SuiteFormatError(f"{where}, field {name!r}: has the wrong type ({value!r})")
        values[name] = value
    for name, allowed in (("suite", LIBERO_SUITES), ("family", families), ("level", LEVELS), ("status", STATUSES)):
        if values[name] not in allowed:
            raise SuiteFormatError(f"{where}, field {name!r}: {values[name]!r} is not one of {', '.join(allowed)}")
    states = values["init_states"]
    if states is not None and not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in states):
        raise SuiteFormatError(f"{where}, field 'init_states': expected non-negative integers, got {states!r}")
    if not all(isinstance(f, str) for f in values["factors"]):
        raise SuiteFormatError(f"{where}, field 'factors': expected a list of strings")
    values["factors"] = tuple(values["factors"])
    values["init_states"] = None if states is None else tuple(states)
    return ConflictCase(**values)


def case_line(case: ConflictCase) -> str:
    return json.dumps(case.to_dict(), sort_keys=True, ensure_ascii=False)


def checksum(lines: Iterable[str]) -> str:
    digest = hashlib.sha256()
    for line in lines:
        digest.update(line.encode("utf-8") + b"\n")
    return digest.hexdigest()


def parse_suite(
    text: str, *, source: str = "<suite>", require_header: bool = False, families: tuple[str, ...] = FAMILIES
) -> Suite:
    """Read a suite file's text; ``families`` widens the accepted families (plugins may add some)."""
    lines = text.splitlines()
    header: dict[str, Any] | None = None
    first = 0
    if lines:
        try:
            head = json.loads(lines[0])
        except json.JSONDecodeError as exc:
            raise SuiteFormatError(f"{source} line 1: not valid JSON ({exc.msg})") from None
        if isinstance(head, dict) and head.get("format") == FORMAT:
            header, first = head, 1
    if header is None and require_header:
        raise SuiteFormatError(f"{source} line 1: missing the '{FORMAT}' header")
    if header is not None and header.get("format_version") != FORMAT_VERSION:
        raise SuiteFormatError(
            f"{source} line 1, field 'format_version': {header.get('format_version')!r}; "
            f"this conflictbench reads version {FORMAT_VERSION}"
        )
    body = [line for line in lines[first:]]
    cases: list[ConflictCase] = []
    seen: dict[str, int] = {}
    for offset, line in enumerate(body):
        number = first + offset + 1
        if not line.strip():
            raise SuiteFormatError(f"{source} line {number}: empty line")
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise SuiteFormatError(f"{source} line {number}: not valid JSON ({exc.msg})") from None
        case = _case_from(obj, f"{source} line {number}", families)
        if case.case_id in seen:
            raise SuiteFormatError(
                f"{source} line {number}, field 'case_id': {case.case_id!r} repeats line {seen[case.case_id]}"
            )
        seen[case.case_id] = number
        cases.append(case)
    if header is not None:
        if header.get("cases") != len(cases):
            raise SuiteFormatError(f"{source} line 1, field 'cases': says {header.get('cases')}, file has {len(cases)}")
        if header.get("sha256") != checksum(body):
            raise SuiteFormatError(
                f"{source} line 1, field 'sha256': checksum mismatch; the cases were changed after the suite was built"
            )
    if not cases:
        raise SuiteFormatError(f"{source} holds no cases")
    name = str(header.get("name", "")) if header else Path(source).stem
    version = str(header.get("version", "")) if header else ""
    return Suite(name=name, version=version, cases=tuple(cases), path=source)


def read_suite(path: str | Path, *, require_header: bool = False, families: tuple[str, ...] = FAMILIES) -> Suite:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SuiteFormatError(f"suite file not found: {path}") from None
    except OSError as exc:  # a directory, no permission
        raise SuiteFormatError(f"cannot read the suite file {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise SuiteFormatError(f"{path}: not UTF-8 text") from None
    return parse_suite(text, source=str(path), require_header=require_header, families=families)


def format_suite(cases: Iterable[ConflictCase], *, name: str, version: str, extra: dict[str, Any] | None = None) -> str:
    """The file text; ``extra`` adds header fields (the build records its seed there)."""
    lines = [case_line(c) for c in cases]
    header = {
        **(extra or {}),
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "name": name,
        "version": version,
        "cases": len(lines),
        "sha256": checksum(lines),
    }
    return "\n".join([json.dumps(header, sort_keys=True)] + lines) + "\n"


def shipped_suite_path() -> Path:
    return Path(str(resources.files("conflictbench.tasks") / "data" / SHIPPED))


def load_suite(path: str | Path | None = None, *, families: tuple[str, ...] = FAMILIES) -> Suite:
    """The shipped suite (header and checksum required), or a suite file the user names."""
    if path is None:
        return read_suite(shipped_suite_path(), require_header=True, families=families)
    return read_suite(path, families=families)
