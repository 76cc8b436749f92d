"""What the suite is made of, beyond cell counts: review removal rates per family x level, where
grounding referents come from, and which kinds of violation the physical family uses."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence

from conflictbench.core import LEVELS, ConflictCase

USABLE = ("accepted", "revised")


def removal_rates(cases: Sequence[ConflictCase], families: Sequence[str], decisions) -> list[tuple[str, str, int, int]]:
    """(family, level, removed, reviewed) per cell, from the review decisions (the latest round's
    decision stands for each case)."""
    from .review import latest

    cell = {c.case_id: (c.family, c.level) for c in cases}
    removed, reviewed = Counter(), Counter()
    for d in latest(decisions):
        if d.case_id in cell:
            reviewed[cell[d.case_id]] += 1
            removed[cell[d.case_id]] += d.decision == "removed"
    return [(f, lv, removed[(f, lv)], reviewed[(f, lv)]) for f in families for lv in LEVELS if reviewed[(f, lv)]]


def _share(counter: Counter) -> str:
    total = sum(counter.values())
    return ", ".join(f"{k} {v} ({100 * v / total:.0f} %)" for k, v in counter.most_common()) if total else "none"


def composition_lines(cases: Sequence[ConflictCase]) -> list[str]:
    usable = [c for c in cases if c.status in USABLE]
    sources = Counter(
        str(r.get("source", "unrecorded"))
        for c in usable
        if c.family == "grounding"
        for r in c.witness.get("referents", [])
    )
    lines = [f"grounding referents by source: {_share(sources)}"]
    for level in LEVELS:
        kinds = Counter(
            str(v.get("kind", "unrecorded"))
            for c in usable
            if c.family == "physical" and c.level == level
            for v in c.witness.get("violations", [])
        )
        lines.append(f"physical {level} violations by kind: {_share(kinds)}")
    return lines


def removal_lines(cases: Sequence[ConflictCase], families: Sequence[str], decisions) -> list[str]:
    rows = removal_rates(cases, families, decisions)
    if not rows:
        return ["review: no decisions for these cases"]
    out = ["review removal rate per family x level (removed / reviewed):"]
    for family, level, removed, reviewed in rows:
        out.append(f"  {family:<12} {level}  {removed:>4} / {reviewed:<4} {100 * removed / reviewed:5.1f} %")
    total_removed, total = sum(r[2] for r in rows), sum(r[3] for r in rows)
    out.append(f"  all              {total_removed:>4} / {total:<4} {100 * total_removed / total:5.1f} %")
    pending = sum(1 for c in cases if c.status == "pending")
    if pending:
        out.append(f"  {pending} case(s) not yet reviewed (pending: no run plays them)")
    return out
