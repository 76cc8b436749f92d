"""``conflictbench suite validate|stats|sample|export|build``: the conflict suite's own verbs."""

from __future__ import annotations

import json
import sys
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from conflictbench.cli.args import Parser
from conflictbench.core import LEVELS, LIBERO_SUITES, PROMPT_CONDITIONS, UserError
from conflictbench.core.plugins import Plugins
from conflictbench.core.words import counted

SUBCOMMANDS = ("validate", "stats", "sample", "export", "build", "review-sheets", "review-merge")
USAGE = """usage: conflictbench suite validate [FILE]          re-check every case (shipped suite by default)
       conflictbench suite stats [FILE] [--markdown]  cases per family x level x LIBERO suite
       conflictbench suite sample --per-cell N [--seed S] [--out FILE]   stratified sample for review
       conflictbench suite export FILE.jsonl [--suite FILE] [--prompts]  one JSON object per case
       conflictbench suite build [--seed S] [--out FILE] [--facts] [--check]  regenerate the suite
       conflictbench suite review-sheets --out DIR [--size N] [--only IDS] [--priors FILE]  batches for readers
       conflictbench suite review-merge VERDICTS.jsonl --reviewer NAME [--round N]  append their decisions
"""


def command(argv: list[str], plugins: Plugins) -> int:
    if not argv:
        raise UserError(
            f"conflictbench suite: name a command: {', '.join(SUBCOMMANDS)} (see: conflictbench suite --help)"
        )
    if argv[0] in ("-h", "--help", "help"):
        print(USAGE, end="")
        return 0
    verb, rest = argv[0], list(argv[1:])
    if verb not in SUBCOMMANDS:
        raise UserError(f"unknown suite command {verb!r}; valid: {', '.join(SUBCOMMANDS)}")
    from conflictbench.cli.suite_review import review_merge, review_sheets

    verbs = {"validate": _validate, "stats": _stats, "sample": _sample, "export": _export, "build": _build}
    verbs |= {"review-sheets": review_sheets, "review-merge": review_merge}
    return verbs[verb](rest, plugins)


def _load(path: str | None, plugins: Plugins):
    from conflictbench.tasks.suite.file import load_suite

    return load_suite(path, families=plugins.families())


def _validate(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite validate", description="Re-check every case of a suite or export.")
    parser.add_argument("file", nargs="?", help="a suite file or a headerless export (default: the shipped suite)")
    parser.add_argument("--facts", help="scene facts file (default: the shipped one)")
    args = parser.parse_args(argv)
    from conflictbench.tasks.validation.rules import new_context, validate_cases

    start = time.perf_counter()
    suite = _load(args.file, plugins)
    ctx = new_context(args.facts, plugins.conflict_operators().values())
    failures = validate_cases(suite.cases, ctx, composition=bool(suite.version))  # a headerless export is a part
    for case_id, reason in failures:
        print(f"{case_id}: {reason}")
    checked = sum(1 for c in suite.cases if c.status != "removed")
    bad = len({cid for cid, _ in failures})
    where = args.file or f"the shipped suite ({suite.name} {suite.version})"
    print(
        f"{counted(checked, 'case')} checked in {time.perf_counter() - start:.1f} s: "
        f"{'all valid' if not bad else f'{bad} invalid'} ({where})",
        file=sys.stderr,
    )
    return 1 if failures else 0


def stats_table(cases, families: Sequence[str], markdown: bool = False) -> str:
    counts = Counter((c.family, c.level, c.suite) for c in cases if c.status in ("accepted", "revised"))
    head = ["family", "level", *LIBERO_SUITES, "total"]
    rows = []
    for family in families:
        for level in LEVELS:
            per = [counts[(family, level, s)] for s in LIBERO_SUITES]
            if family in families[:4] or sum(per):
                rows.append([family, level, *map(str, per), str(sum(per))])
    per_suite = [sum(counts[(f, lv, s)] for f in families for lv in LEVELS) for s in LIBERO_SUITES]
    rows.append(["all", "", *map(str, per_suite), str(sum(per_suite))])
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows]) + "\n"
    widths = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    fmt = lambda r: "  ".join(x.ljust(w) if i < 2 else x.rjust(w) for i, (x, w) in enumerate(zip(r, widths)))  # noqa: E731
    return "\n".join([fmt(head), *map(fmt, rows)]) + "\n"


def _stats(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite stats", description="Usable cases per family x level x LIBERO suite.")
    parser.add_argument("file", nargs="?", help="a suite file or export (default: the shipped suite)")
    parser.add_argument("--markdown", action="store_true", help="print a Markdown table (as in the README)")
    parser.add_argument("--reviews", help="review decisions for the removal rates (default: the shipped ones)")
    args = parser.parse_args(argv)
    from conflictbench.tasks.suite.review import load_reviews

    suite = _load(args.file, plugins)
    decisions = load_reviews(args.reviews) if args.reviews or not args.file else []  # a bad file: before any output
    print(stats_table(suite.cases, plugins.families(), args.markdown), end="")
    status = Counter(c.status for c in suite.cases)
    tasks = len({(c.suite, c.task_id) for c in suite.accepted()})
    print(f"statuses: {', '.join(f'{k} {v}' for k, v in sorted(status.items()))}; base tasks used: {tasks}")
    from conflictbench.tasks.suite.stats import composition_lines, removal_lines

    print("\n".join(composition_lines(suite.cases) + removal_lines(suite.cases, plugins.families(), decisions)))
    return 0


def _sample(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite sample", description="A stratified sample of cases for manual review.")
    parser.add_argument("--per-cell", type=int, required=True, metavar="N", help="cases per family x level cell")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--suite", help="suite file (default: the shipped suite)")
    parser.add_argument("--out", help="write the review sheet here (JSON Lines) instead of printing it")
    args = parser.parse_args(argv)
    if args.per_cell < 1:
        raise UserError(f"--per-cell must be at least 1, got {args.per_cell}")
    from conflictbench.tasks.suite.review import review_template, sample_for_review

    picked = sample_for_review(_load(args.suite, plugins).cases, args.per_cell, args.seed)
    lines = [json.dumps(review_template(c), ensure_ascii=False) for c in picked]
    if args.out:
        _write(Path(args.out), "\n".join(lines) + "\n")
        print(
            f"wrote {counted(len(lines), 'case')} to {args.out}; to have them read, give their ids to "
            "`conflictbench suite review-sheets --only`, then `review-merge` the verdicts (--round 2 for a recheck)",
            file=sys.stderr,
        )
    else:
        print("\n".join(lines))
    return 0


EXPORT_KEYS = (
    "case_id",
    "suite",
    "task_id",
    "base_instruction",
    "instruction",
    "family",
    "level",
    "factors",
    "premise",
    "witness",
    "status",
    "init_states",
)


def _export(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite export", description="Every case, one JSON object per line.")
    parser.add_argument("out", metavar="FILE.jsonl")
    parser.add_argument("--suite", help="suite file (default: the shipped suite)")
    parser.add_argument(
        "--prompts",
        action="store_true",
        help=f"one line per case and prompt condition ({', '.join(PROMPT_CONDITIONS)}), with the prompt text",
    )
    parser.add_argument(
        "--policy", default="", help="policy whose prompt format to use with --prompts (default: the core's)"
    )
    args = parser.parse_args(argv)
    suite = _load(args.suite, plugins)
    lines = []
    for case in suite.cases:
        row = {k: v for k, v in case.to_dict().items() if k in EXPORT_KEYS}
        if not args.prompts:
            lines.append(json.dumps(row, sort_keys=True, ensure_ascii=False))
            continue
        for condition in PROMPT_CONDITIONS:
            prompt = plugins.format_prompt(case.instruction, condition, args.policy)
            lines.append(
                json.dumps({**row, "prompt": condition, "prompt_text": prompt}, sort_keys=True, ensure_ascii=False)
            )
    _write(Path(args.out), "\n".join(lines) + ("\n" if lines else ""))
    print(f"wrote {len(lines)} lines to {args.out}", file=sys.stderr)
    return 0


def _build(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(prog="conflictbench suite build", description="Generate the suite from the base tasks.")
    parser.add_argument("--seed", type=int, default=None, help="generation seed (default: 0, the shipped suite's)")
    parser.add_argument("--out", help="where to write (default: the shipped suite file)")
    parser.add_argument(
        "--facts",
        action="store_true",
        help="first re-derive the scene facts from the simulator (minutes; needs LIBERO)",
    )
    parser.add_argument(
        "--reviews", help="review decisions file (default: the shipped one, which applies to seed 0 only)"
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 if the build differs from the file (determinism check)",
    )
    args = parser.parse_args(argv)
    from conflictbench.tasks.libero.base_tasks import all_base_tasks
    from conflictbench.tasks.scene.facts import shipped_facts_path
    from conflictbench.tasks.suite.build import DEFAULT_SEED, build_suite_text
    from conflictbench.tasks.suite.file import shipped_suite_path

    target = Path(args.out) if args.out else shipped_suite_path()
    progress = (lambda m: print(f"  {m}", file=sys.stderr)) if sys.stderr.isatty() else None  # noqa: E731
    if args.facts:
        from conflictbench.sim.scene_facts import build_scene_facts

        build_scene_facts(all_base_tasks(), shipped_facts_path(), progress=lambda m: print(f"  {m}", file=sys.stderr))
    seed = DEFAULT_SEED if args.seed is None else args.seed
    text = build_suite_text(seed=seed, plugins=plugins, reviews_path=args.reviews, progress=progress)
    if args.check:
        same = target.exists() and target.read_text(encoding="utf-8") == text
        print(
            f"{target}: {'identical to a fresh build' if same else 'differs from a fresh build'} (seed {seed})",
            file=sys.stderr,
        )
        return 0 if same else 1
    _write(target, text)
    print(f"wrote {counted(text.count(chr(10)) - 1, 'case')} to {target} (seed {seed})", file=sys.stderr)
    return 0


def _write(path: Path, text: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror}") from None
