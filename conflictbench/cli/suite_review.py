"""``conflictbench suite review-sheets|review-merge``: every case read by an independent reviewer.

``review-sheets`` writes the usable cases (or the ones listed) as Markdown batches, each with the
reviewers' brief and the facts of each scene; ``review-merge`` turns a reader's verdicts into
decisions appended to the review file the build honours.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

from conflictbench.cli.args import Parser
from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins


def review_sheets(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite review-sheets", description="Cases and scene facts for reviewers.")
    parser.add_argument("--out", required=True, help="directory for the batch sheets (batch-NNN.md)")
    parser.add_argument("--size", type=int, default=60, help="cases per batch (default 60)")
    parser.add_argument("--suite", help="suite file (default: the shipped suite)")
    parser.add_argument(
        "--only", help="a file of case ids (one per line), removed ones included: e.g. the flagged ones for round 2"
    )
    parser.add_argument("--priors", help="round-1 decisions (JSON Lines) whose notes the sheets show")
    parser.add_argument("--seed", type=int, default=0, help="seed of the batches' shuffle")
    args = parser.parse_args(argv)
    from conflictbench.tasks.suite.file import load_suite
    from conflictbench.tasks.suite.review import read_text
    from conflictbench.tasks.suite.review_sheets import write_batches
    from conflictbench.tasks.validation.rules import new_context

    suite = load_suite(args.suite, families=plugins.families())
    cases = [c for c in suite.cases if c.status != "removed"]
    if args.only:  # named cases, removed ones too: a round-2 recheck reads what round 1 removed
        cases = list(suite.cases)
        wanted = set(read_text(Path(args.only)).split())
        unknown = wanted - {c.case_id for c in cases}
        if unknown:
            raise UserError(f"{args.only}: {len(unknown)} case id(s) not in the suite, e.g. {sorted(unknown)[0]}")
        cases = [c for c in cases if c.case_id in wanted]
    priors = {}
    if args.priors:
        from conflictbench.tasks.suite.review_sheets import read_verdicts

        for row in read_verdicts(Path(args.priors)):
            if not isinstance(row, dict) or not isinstance(row.get("case_id"), str):
                raise UserError(f"{args.priors}: every line needs a case_id (and the first reader's note)")
            priors[row["case_id"]] = str(row.get("note", ""))
    ctx = new_context(None, plugins.conflict_operators().values())
    models = {(c.suite, c.task_id): ctx.model((c.suite, c.task_id)) for c in cases}
    paths = write_batches(cases, models, Path(args.out), args.size, seed=args.seed, priors=priors)
    print(f"wrote {len(cases)} cases in {len(paths)} batch(es) to {args.out}", file=sys.stderr)
    return 0


def review_merge(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite review-merge", description="Append a reader's verdicts as decisions.")
    parser.add_argument("verdicts", nargs="+", help="JSON Lines files of {case_id, verdict, note}")
    parser.add_argument("--reviewer", required=True, help="who read them (never the cases' author)")
    parser.add_argument("--round", type=int, default=1, help="1: first reading; 2: recheck of flagged cases")
    parser.add_argument("--reviews", help="decisions file to append to (default: the shipped one)")
    parser.add_argument("--suite", help="the suite the verdicts are about (default: the shipped one)")
    args = parser.parse_args(argv)
    from conflictbench.tasks.suite.file import load_suite
    from conflictbench.tasks.suite.review import load_reviews, parse_reviews, read_text, review_path
    from conflictbench.tasks.suite.review_sheets import decisions_from_verdicts, read_verdicts

    target = Path(args.reviews) if args.reviews else review_path()
    rows = [r for path in args.verdicts for r in read_verdicts(Path(path))]
    new = decisions_from_verdicts(rows, args.reviewer, args.round)
    known = {c.case_id for c in load_suite(args.suite, families=plugins.families()).cases}
    unknown = sorted({d["case_id"] for d in new} - known)
    if unknown:  # appended, it would stop the next build ("not produced by the generator")
        raise UserError(f"{len(unknown)} verdict(s) name cases the suite does not have, e.g. {unknown[0]}")
    earlier = load_reviews(target) if target.exists() else []
    same_reader = {d.case_id for d in earlier if d.reviewer == args.reviewer} & {d["case_id"] for d in new}
    if args.round > 1 and same_reader:
        raise UserError(f"{args.reviewer} already decided {sorted(same_reader)[0]}: a recheck needs another reader")
    text = "".join(json.dumps(d, ensure_ascii=False) + "\n" for d in new)
    old = read_text(target) if target.exists() else ""
    parse_reviews(old + text, str(target))  # refuses a second decision for a case in one round
    try:
        target.write_text(old + text, encoding="utf-8")
    except OSError as exc:
        raise UserError(f"cannot write {target}: {exc.strerror}") from None
    print(f"appended {len(new)} decision(s) to {target}", file=sys.stderr)
    return 0
