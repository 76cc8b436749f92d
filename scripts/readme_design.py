"""README's figures on what a slice can tell apart: the correlations measured on the learned subject, the widest
interval on dSR per family of a few slices (the plan line's bound), and the initial states two models need.

    .venv/bin/python scripts/readme_design.py            writes the block into README.md
    .venv/bin/python scripts/readme_design.py --check    exit 1, showing the difference, where README's is not current

Everything comes from conflictbench/metrics/correlations.json (scripts/measure_correlations.py, from a real store),
the shipped suite and conflictbench/metrics/design.py; nothing is played. A test checks that the block is current.
"""

from __future__ import annotations

import argparse
import sys

from readme_block import ReadmeBlock

BEGIN = "<!-- scripts/readme_design.py writes what follows, from correlations.json and the suite; do not edit it -->"
END = "<!-- end of scripts/readme_design.py -->"
BLOCK = ReadmeBlock("readme_design", BEGIN, END)
SLICES = (
    ("the default slice (`conflictbench`)", 1, 1),
    ("`run.init_states=3 run.cases_per_cell=4`", 4, 3),
    ("`run.cases_per_cell=10`", 10, 1),
    ("`run=paper` (every case, 5 initial states)", None, 5),
    ("every case, 10 initial states", None, 10),
)
DIFFERENCES = (0.10, 0.15, 0.20)


def plan(cases_per_cell: int | None, states: int):
    from conflictbench.core import FAMILIES, LEVELS
    from conflictbench.sim.plan import build_plan
    from conflictbench.tasks.suite.file import load_suite

    suite = load_suite(None)
    tasks = {(c.suite, c.task_id): c.base_instruction for c in suite.cases}
    return build_plan(suite.cases, base_instructions=tasks, families=FAMILIES, levels=LEVELS, prompts=("p0",),
                      init_states=list(range(states)), cases_per_cell=cases_per_cell)  # fmt: skip


def block() -> str:
    from collections import Counter

    from conflictbench.metrics.design import correlations, design, family_layouts, states_needed, worst_half_width

    measured = correlations()
    source = measured["provenance"]
    lines = [
        BEGIN,
        "",
        f"Measured on the learned subject ({source['pairs']} pairs of {source['base_tasks']} base tasks and "
        f"{source['cases']} cases, {source['episodes']} episodes of `conflictbench model=subject run.init_states=3 "
        f"run.cases_per_cell=4`, then `{source['command']}`), the mean correlation between two pairs of one base "
        "task:",
        "",
        "| measure | same case, other initial state | same initial state (so the same reference), other case "
        "| the task only |",
        "| --- | ---: | ---: | ---: |",
    ]
    for name, label in (("conflict_success", "conflict success (y-)"), ("dSR", "dSR of the pair (y+ - y-)"),
                        ("ts", "TS")):  # fmt: skip
        r = measured[name]
        lines.append(f"| {label} | {r['case']:.2f} | {r['state']:.2f} | {r['task']:.2f} |")
    lines.append(f"| reference success (y+), across initial states | | | {measured['reference_success']['task']:.2f} |")
    from conflictbench.core import FAMILIES
    from conflictbench.metrics.design import plan_line

    lines += ["", "The plan line of `run=paper`:", "", "```", f"conflictbench: {plan_line(plan(None, 5), FAMILIES)}",
              "```"]  # fmt: skip
    lines += [
        "",
        "The widest 95 % interval on dSR per family a slice can give (the plan line's bound: its half-width at dSR "
        "= 0, at the degrees of freedom alike base tasks give; its intra-cluster correlation is what the measured "
        "ones amount to for that slice):",
        "",
        "| slice | pairs a family (the widest) | base tasks | intra-cluster correlation | half-width on dSR |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for label, cases, states in SLICES:
        layouts = family_layouts(plan(cases, states))
        widest = max(layouts, key=lambda f: worst_half_width(design(layouts[f])))
        d = design(layouts[widest])
        half = worst_half_width(d)
        icc = "-" if d.pairs <= d.clusters else f"{d.icc:.2f}"
        lines.append(f"| {label} | {d.pairs:,} | {d.clusters} | {icc} | ±{100 * half:.0f} pp |")
    difference = measured["between_models"]["dSR_difference"]
    variance = difference["variance"]
    corr = tuple(max(0.0, difference[k]) for k in ("task", "case", "state"))
    every = plan(None, 1)
    overall = Counter((e.suite, e.task_id) for e in every if e.case is not None)
    per_family = {f: {i: c for i, (c, _) in enumerate(lay)} for f, lay in family_layouts(every).items()}
    lines += [
        "",
        "Initial states (of LIBERO's 50) that two models need, every case played, to tell a difference in dSR apart "
        "with 80 % power, from the difference measured between two settings of the subject on the same pairs (`model."
        f"sample_gripper` true and false): its variance a pair, {variance:.2f}, and its correlations within a task "
        f"(same case {corr[1]:.2f}, same initial state {corr[2]:.2f}, the task only {corr[0]:.2f}); a family row at "
        "5 % / 4, Holm's first step. Two unrelated models differ more from pair to pair, and need more. The coverage "
        "simulation (tests/test_coverage.py), whose two models share latent effects fitted one measure at a time, "
        "finds less power at the paper's size than this formula: which holds for two given models depends on how "
        "differently they fare task by task.",
        "",
        "| dSR difference | overall | per family (the one that needs the most) |",
        "| ---: | ---: | ---: |",
    ]
    for difference in DIFFERENCES:
        whole = states_needed(overall, difference, variance, corr)
        families = [states_needed(c, difference, variance, corr, alpha=0.05 / 4) for c in per_family.values()]
        worst = None if any(n is None for n in families) else max(families)
        lines.append(f"| {100 * difference:.0f} points | {_states(whole)} | {_states(worst)} |")
    ceiling = len(overall) / corr[0] if corr[0] > 0 else float("inf")
    lines += [
        "",
        f"More initial states cannot make up for the {len(overall)} base tasks: pairs correlated {corr[0]:.2f} within "
        f"a task count as at most about {len(overall)} / {corr[0]:.2f} = {ceiling:.0f} independent ones, however "
        "many are played.",
    ]
    return "\n".join([*lines, "", END])


def _states(n: int | None) -> str:
    return "more than 50" if n is None else str(n)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare with README instead of writing it")
    args = parser.parse_args(argv)
    BLOCK.current()  # no block to put it in: said before the work
    return BLOCK.write_or_check(block(), args.check, "design figures")


if __name__ == "__main__":
    sys.exit(main())
