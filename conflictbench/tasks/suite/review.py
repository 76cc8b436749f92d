"""Review: every case is read by a reviewer that did not write it, and the build honours the decisions.

Decisions live beside the suite in ``data/review.jsonl``, one per line::

    {"case_id": "...", "decision": "accepted" | "revised" | "removed", "note": "why",
     "reviewer": "reader-07", "round": 1,
     "instruction": "...", "premise": "...", "witness": {...}}   # the last three only for "revised"

Round 1 reads every case; a case flagged there is read again in round 2 by another reviewer, and
the decision of the latest round stands (one decision per case and round). With
``require_review`` (the shipped suite), a case nobody has decided on gets status ``pending`` and
no run plays it. The build applies the decisions after generation: a removed case stays in the file with status
``removed`` (its id stays reserved, planners skip it); a revised case takes the reviewer's text and
status ``revised`` and must still pass validation (the witness, the reviewer's if given, must point
into the new text: rewording around the witnessed phrases keeps the original witness valid); an
accepted one keeps status ``accepted``. A decision for a case the generator no longer produces
stops the build: the generator changed under the reviewer, and the sample needs a new look.
"""

from __future__ import annotations

import random
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

from conflictbench.core import ConflictCase, UserError
from conflictbench.tasks.json_lines import json_objects
from conflictbench.tasks.validation.factors import with_components

REVIEW_FILE = "review.jsonl"
DECISIONS = ("accepted", "revised", "removed")


class ReviewError(UserError):
    pass


@dataclass(frozen=True)
class Decision:
    case_id: str
    decision: str
    note: str
    instruction: str | None = None
    premise: str | None = None
    witness: dict | None = None
    line: int = 0
    reviewer: str = ""
    round: int = 1


def review_path() -> Path:
    return Path(str(resources.files("conflictbench.tasks") / "data" / REVIEW_FILE))


def parse_reviews(text: str, source: str) -> list[Decision]:
    out: list[Decision] = []
    seen: dict[tuple[str, int], int] = {}
    for number, where, row in json_objects(text, source, ReviewError, blank_lines=True):
        for key in ("case_id", "decision", "note"):
            if not isinstance(row.get(key), str) or (key != "note" and not row[key]):
                raise ReviewError(f"{where}, field {key!r}: missing or not a string")
        if row["decision"] not in DECISIONS:
            raise ReviewError(f"{where}, field 'decision': {row['decision']!r} is not one of {', '.join(DECISIONS)}")
        if row["decision"] == "revised" and not isinstance(row.get("instruction"), str):
            raise ReviewError(f"{where}, field 'instruction': a revised case needs its new instruction")
        if row.get("witness") is not None and not isinstance(row["witness"], dict):
            raise ReviewError(f"{where}, field 'witness': expected a JSON object")
        if not isinstance(row.get("reviewer", ""), str):
            raise ReviewError(f"{where}, field 'reviewer': expected a string")
        round_ = row.get("round", 1)
        if not isinstance(round_, int) or isinstance(round_, bool) or round_ < 1:
            raise ReviewError(f"{where}, field 'round': expected a whole number from 1")
        key = (row["case_id"], round_)
        if key in seen:
            raise ReviewError(
                f"{where}, field 'case_id': {row['case_id']!r} was decided in round {round_} on line {seen[key]}"
            )
        seen[key] = number
        out.append(
            Decision(
                row["case_id"],
                row["decision"],
                row["note"],
                row.get("instruction"),
                row.get("premise"),
                row.get("witness"),
                number,
                row.get("reviewer", ""),
                round_,
            )
        )
    return out


def load_reviews(path: str | Path | None = None) -> list[Decision]:
    p = Path(path) if path else review_path()
    if not p.exists():
        if path:
            raise ReviewError(f"review file not found: {p}")
        return []
    return parse_reviews(read_text(p, "the review file "), str(p))


def read_text(path: Path, what: str = "") -> str:
    """A review file's text, or one line saying why it cannot be read (a directory, no permission,
    not UTF-8): a user's mistake, never a traceback."""
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ReviewError(f"cannot read {what}{path}: {getattr(exc, 'strerror', None) or exc}") from None


def latest(decisions: Iterable[Decision]) -> list[Decision]:
    """The decision that stands for each case: its latest round's."""
    out: dict[str, Decision] = {}
    for d in decisions:
        if d.case_id not in out or d.round > out[d.case_id].round:
            out[d.case_id] = d
    return list(out.values())


def apply_reviews(
    cases: Sequence[ConflictCase], decisions: Iterable[Decision], ctx=None, *, require_review: bool = False
) -> list[ConflictCase]:
    from conflictbench.tasks.validation.rules import validate_case

    by_id = {c.case_id: i for i, c in enumerate(cases)}
    out = list(cases)
    decisions = list(decisions)
    for d in decisions:
        if d.case_id not in by_id:
            raise ReviewError(
                f"review line {d.line}: case {d.case_id!r} is not produced by the generator any more; "
                "review the new sample and update the decision"
            )
    if require_review:
        decided = {d.case_id for d in decisions}
        out = [c if c.case_id in decided else replace(c, status="pending") for c in out]
    for d in latest(decisions):
        i = by_id[d.case_id]
        case = out[i]
        if d.decision == "removed":
            out[i] = replace(case, status="removed")
        elif d.decision == "revised":
            out[i] = replace(
                case,
                instruction=d.instruction,
                premise=d.premise or case.premise,
                # which components each factor touches follows from the reviewer's witness
                witness=with_components(d.witness) if d.witness else case.witness,
                status="revised",
            )
            if ctx is not None:
                problems = validate_case(out[i], ctx)
                if problems:
                    raise ReviewError(f"review line {d.line}: the revised {d.case_id} fails validation: {problems[0]}")
        else:
            out[i] = replace(case, status="accepted")
    return out


def sample_for_review(cases: Sequence[ConflictCase], per_cell: int, seed: int = 0) -> list[ConflictCase]:
    """At most ``per_cell`` usable cases per (family, level), spread over LIBERO suites and base
    tasks: suites take turns in a seeded order, and within a suite no base task repeats before
    every other task of the suite had its turn."""
    cells: dict[tuple[str, str], list[ConflictCase]] = defaultdict(list)
    for c in cases:
        if c.status in ("accepted", "revised"):
            cells[(c.family, c.level)].append(c)
    chosen: list[ConflictCase] = []
    for cell in sorted(cells):
        rng = random.Random(f"review|{seed}|{cell[0]}|{cell[1]}")
        by_suite: dict[str, list[ConflictCase]] = defaultdict(list)
        for c in sorted(cells[cell], key=lambda c: c.case_id):
            by_suite[c.suite].append(c)
        for group in by_suite.values():
            rng.shuffle(group)
            turn: dict[int, int] = defaultdict(int)
            ranked = []
            for c in group:  # the n-th case of a task gets turn n: tasks alternate
                ranked.append((turn[c.task_id], c))
                turn[c.task_id] += 1
            group[:] = [c for _, c in sorted(ranked, key=lambda r: r[0])]
        order = sorted(by_suite)
        rng.shuffle(order)
        picked: list[ConflictCase] = []
        while len(picked) < per_cell and any(by_suite.values()):
            for suite in order:
                if by_suite[suite] and len(picked) < per_cell:
                    picked.append(by_suite[suite].pop(0))
        chosen += picked
    return sorted(chosen, key=lambda c: (c.family, c.level, c.case_id))


def review_template(case: ConflictCase) -> dict:
    """One line of a review sheet: the case as a reviewer needs it, with the decision left blank."""
    return {
        "case_id": case.case_id,
        "family": case.family,
        "level": case.level,
        "suite": case.suite,
        "task_id": case.task_id,
        "base_instruction": case.base_instruction,
        "instruction": case.instruction,
        "premise": case.premise,
        "factors": list(case.factors),
        "decision": "",
        "note": "",
    }
