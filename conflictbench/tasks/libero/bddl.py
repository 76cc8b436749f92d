"""A small reader for LIBERO's BDDL problem files.

LIBERO's own parser lives in ``libero.libero.envs`` and drags robosuite and MuJoCo in with it;
planning and suite building only need the problem's declarations, so we read them here (a test
checks the result against LIBERO's parser for every base task).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

SExpr = str | list["SExpr"]
_TOKEN = re.compile(r"\(|\)|[^\s()]+")


class BDDLError(ValueError):
    pass


@dataclass(frozen=True)
class Region:
    name: str
    """Full name as the simulator knows it: ``<target>_<region>`` (e.g. ``flat_stove_1_cook_region``)."""
    target: str
    ranges: tuple[tuple[float, ...], ...] = ()


@dataclass(frozen=True)
class BDDLProblem:
    problem_name: str
    language: str
    fixtures: dict[str, str] = field(default_factory=dict)
    """Fixture instance name -> category."""
    objects: dict[str, str] = field(default_factory=dict)
    """Movable object instance name -> category."""
    regions: dict[str, Region] = field(default_factory=dict)
    obj_of_interest: tuple[str, ...] = ()
    init: tuple[tuple[str, ...], ...] = ()
    goal: tuple[tuple[str, ...], ...] = ()
    """Goal predicates (the conjunction's members), predicate names lower-cased."""


def parse_sexpr(text: str) -> list[SExpr]:
    stack: list[list[SExpr]] = [[]]
    for token in _TOKEN.findall(text):
        if token == "(":
            stack.append([])
        elif token == ")":
            if len(stack) == 1:
                raise BDDLError("unbalanced ')'")
            done = stack.pop()
            stack[-1].append(done)
        else:
            stack[-1].append(token)
    if len(stack) != 1:
        raise BDDLError("unbalanced '('")
    return stack[0]


def _typed_names(items: list[SExpr]) -> dict[str, str]:
    """``a b - cat c - cat2`` -> ``{a: cat, b: cat, c: cat2}``."""
    out: dict[str, str] = {}
    pending: list[str] = []
    it = iter(items)
    for tok in it:
        if tok == "-":
            category = next(it)
            for name in pending:
                out[name] = str(category)
            pending = []
        else:
            pending.append(str(tok))
    if pending:
        raise BDDLError(f"names without a category: {pending}")
    return out


def _predicates(items: list[SExpr]) -> tuple[tuple[str, ...], ...]:
    out: list[tuple[str, ...]] = []
    for item in items:
        if not isinstance(item, list) or not item:
            raise BDDLError(f"malformed predicate: {item!r}")
        head = str(item[0]).lower()
        if head in ("and",):
            out.extend(_predicates(item[1:]))
        else:
            out.append((head, *(str(a) for a in item[1:])))
    return tuple(out)


def _region(entry: list[SExpr]) -> Region:
    short = str(entry[0])
    target, ranges = "", ()
    for part in entry[1:]:
        if isinstance(part, list) and part and part[0] == ":target":
            target = str(part[1])
        elif isinstance(part, list) and part and part[0] == ":ranges":
            ranges = tuple(tuple(float(x) for x in r) for r in part[1])
    return Region(name=f"{target}_{short}", target=target, ranges=ranges)


def parse_problem(text: str) -> BDDLProblem:
    top = parse_sexpr(text)
    if len(top) != 1 or not isinstance(top[0], list) or top[0][:1] != ["define"]:
        raise BDDLError("not a BDDL problem: expected (define (problem ...) ...)")
    body = top[0]
    fields: dict[str, object] = {"problem_name": str(body[1][1])}
    for section in body[2:]:
        if not isinstance(section, list) or not section:
            continue
        key, rest = section[0], section[1:]
        if key == ":language":
            fields["language"] = " ".join(str(t) for t in rest)
        elif key == ":fixtures":
            fields["fixtures"] = _typed_names(rest)
        elif key == ":objects":
            fields["objects"] = _typed_names(rest)
        elif key == ":regions":
            regions = [_region(r) for r in rest]
            fields["regions"] = {r.name: r for r in regions}
        elif key == ":obj_of_interest":
            fields["obj_of_interest"] = tuple(str(t) for t in rest)
        elif key == ":init":
            fields["init"] = _predicates(rest)
        elif key == ":goal":
            fields["goal"] = _predicates(rest)
    if "language" not in fields or "goal" not in fields:
        raise BDDLError("BDDL problem lacks :language or :goal")
    return BDDLProblem(**fields)  # type: ignore[arg-type]


def read_problem(path: str | Path) -> BDDLProblem:
    path = Path(path)
    try:
        return parse_problem(path.read_text(encoding="utf-8"))
    except BDDLError as exc:
        raise BDDLError(f"{path}: {exc}") from None
