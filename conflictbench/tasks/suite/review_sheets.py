"""Review sheets: every case with the facts of its scene, in batches for independent readers.

A reader gets the brief (``data/review_brief.md``: the paper's family and level definitions and
what makes a case wrong or questionable), then per base task the facts of its scene (what is there,
what each thing is called, what its category affords, what holds initially and where things
stand), then the cases. Nothing else: not the generator, not the rules' code. The reader's answers
(one JSON line per case: verdict and note) become decisions with :func:`decisions_from_verdicts`.
"""

from __future__ import annotations

import json
import random
from collections import defaultdict
from collections.abc import Iterable, Sequence
from importlib import resources
from pathlib import Path

from conflictbench.core import ConflictCase, UserError
from conflictbench.tasks.scene.affordances import AFFORDANCES, category, load_table
from conflictbench.tasks.scene.lexicon import colourings
from conflictbench.tasks.scene.task_model import TaskModel

VERDICTS = ("valid", "questionable", "wrong")
BRIEF = "review_brief.md"


def brief_text() -> str:
    return (resources.files("conflictbench.tasks") / "data" / BRIEF).read_text(encoding="utf-8")


def _affords(cat: str) -> str:
    if cat not in load_table():
        return ""
    info = category(cat)
    said = {True: "yes", False: "no", None: "unclear"}
    parts = [f"{a} {said[info.has(a)]}" for a in AFFORDANCES]
    known = colourings().get(cat)
    colour = f"; colour {' and '.join(known.colours)}" if known else "; colour not recorded"
    return f"{colour}; size class {info.size}; " + ", ".join(parts)


def scene_sheet(model: TaskModel) -> str:
    """The facts of one base task's scene, as a reader needs them."""
    facts, task = model.facts, model.task
    n = facts.n_states
    lines = [
        f"### Scene: {task.suite} task {task.task_id}",
        f'Reference instruction: "{task.language}". Goal checked by the simulator: '
        + ", ".join("(" + " ".join(a) + ")" for a in task.goal),
        "",
        "Things in the scene (name as instructions use it; identifier; category; movable or fixed; affordances):",
    ]
    for name, entity in sorted(facts.entities.items()):
        if entity.kind == "region":
            continue
        called = model.names.get(name, "(no unambiguous name: a twin of another)")
        lines.append(f"- {called} [{name}; {entity.category}; {entity.kind}{_affords(entity.category)}]")
    regions = [(r, model.dest_phrases[r]) for r in sorted(model.dest_phrases) if r not in model.names]
    if regions:
        lines.append("Named places: " + "; ".join(f"{' '.join(p).strip()} [{r}]" for r, p in regions))
    held = []
    named = set(model.names) | set(model.dest_phrases)
    for atom, states in sorted(facts.predicates.items()):
        # only atoms about things an instruction can name (not LIBERO's placement regions)
        if states and atom[0] in ("on", "in", "open", "close", "turnon", "turnoff") and set(atom[1:]) <= named:
            held.append(f"({' '.join(atom)})" + ("" if len(states) == n else f" in {len(states)} of {n} states"))
    lines.append(f"Initially true (all {n} initial states unless said): " + ", ".join(held))
    lines.append(
        "Positions in initial state 0, centimetres (x: towards the camera = front; y: the image's right, "
        "which is the robot's left; z: up), with each thing's footprint radius r: "
        + "; ".join(
            f"{model.names.get(e, e)} ({p[0][0] * 100:.0f}, {p[0][1] * 100:.0f}, {p[0][2] * 100:.0f}; "
            f"r {(facts.entities[e].radius or 0) * 100:.0f})"
            for e, p in sorted(facts.positions.items())
            if facts.entities[e].kind != "region"
        )
    )
    return "\n".join(lines)


def case_sheet(case: ConflictCase, prior: str = "", model: TaskModel | None = None) -> str:
    w = case.witness
    keep = {k: v for k, v in w.items() if k not in ("type", "steps", "step_goals", "step_entities")}
    lines = [
        f"#### {case.case_id} — {case.family}, {case.level}",
        f'Instruction: "{case.instruction}"',
        f"Steps: {json.dumps(w.get('steps', []), ensure_ascii=False)}"
        + (f" (roles: {', '.join(w['step_roles'])})" if w.get("step_roles") else ""),
        f"Stated premise (what makes it invalid): {case.premise}",
        f"Factors: {'; '.join(case.factors)}",
        f"Witness: {json.dumps(keep, ensure_ascii=False)}",
    ]
    if case.init_states is not None:
        lines.append(f"Paired only with initial states {list(case.init_states)}")
        if model is not None and 0 not in case.init_states:  # the scene's positions are state 0's
            first = case.init_states[0]
            lines.append(
                f"Positions in initial state {first}, centimetres: "
                + "; ".join(
                    f"{model.names.get(e, e)} ({x * 100:.0f}, {y * 100:.0f}, {z * 100:.0f})"
                    for e, p in sorted(model.facts.positions.items())
                    for x, y, z in [p[first]]
                    if model.facts.entities[e].kind != "region"
                )
            )
    if prior:
        lines.append(f"A first reader flagged it: {prior}")
    return "\n".join(lines)


def write_batches(
    cases: Sequence[ConflictCase],
    models: dict[tuple[str, int], TaskModel],
    out_dir: Path,
    size: int,
    *,
    seed: int = 0,
    priors: dict[str, str] | None = None,
) -> list[Path]:
    """Shuffle the cases (seeded), cut batches of about ``size``, and write each as a Markdown sheet
    grouped by base task (brief, then each scene once, then its cases). Returns the sheet paths."""
    if size < 1:
        raise UserError(f"batch size must be at least 1, got {size}")
    order = sorted(cases, key=lambda c: c.case_id)
    random.Random(f"review-batches|{seed}").shuffle(order)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for start in range(0, len(order), size):
        batch = order[start : start + size]
        by_task: dict[tuple[str, int], list[ConflictCase]] = defaultdict(list)
        for c in batch:
            by_task[(c.suite, c.task_id)].append(c)
        parts = [brief_text(), f"\n## Cases ({len(batch)})\n"]
        for key in sorted(by_task):
            parts.append(scene_sheet(models[key]))
            parts += [case_sheet(c, (priors or {}).get(c.case_id, ""), models[key]) for c in by_task[key]]
        path = out_dir / f"batch-{start // size + 1:03d}.md"
        path.write_text("\n\n".join(parts) + "\n", encoding="utf-8")
        paths.append(path)
    return paths


def decisions_from_verdicts(rows: Iterable[dict], reviewer: str, round_: int) -> list[dict]:
    """A reader's verdicts as review decisions: valid -> accepted; wrong or questionable -> removed."""
    if not reviewer.strip():
        raise UserError("--reviewer must name who read the cases")
    out = []
    for row in rows:
        fields = (row.get("case_id"), row.get("verdict"), row.get("note")) if isinstance(row, dict) else ()
        if len(fields) != 3 or not all(isinstance(f, str) and f.strip() for f in fields) or fields[1] not in VERDICTS:
            raise UserError(f"a verdict needs case_id, verdict ({', '.join(VERDICTS)}) and a note, as strings: {row}")
        case_id, verdict, note = fields
        out.append(
            {
                "case_id": case_id,
                "decision": "accepted" if verdict == "valid" else "removed",
                "note": f"{verdict}: {note.strip()}",
                "reviewer": reviewer,
                "round": round_,
            }
        )
    return out


def read_verdicts(path: Path) -> list[dict]:
    from .review import read_text

    rows = []
    for number, line in enumerate(read_text(path).splitlines(), start=1):
        if line.strip():
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise UserError(f"{path} line {number}: not valid JSON ({exc.msg})") from None
    return rows
