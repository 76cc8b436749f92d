"""``conflictbench reproduce model=M model.checkpoint=DIR model.published=ENTRY``: LIBERO's standard evaluation
(the original instructions, prompt p0, all 50 fixed initial states of the entry's suites) through the same run as
the benchmark, so its reference episodes are the benchmark's; then per suite the measured success with its 95 %
Wilson interval beside the published figure, and a verdict."""

from __future__ import annotations

import sys

from conflictbench.core import UserError
from conflictbench.core.plugins import Plugins

from . import run
from .published import KEY, check_declaration, take_declaration
from .run_options import INIT_STATES_PER_TASK

QUICK_INIT_STATES = 2
USAGE = (
    "usage: conflictbench reproduce model=M model.checkpoint=DIR model.published=ENTRY [--quick] [OVERRIDE ...]\n"
    "  plays LIBERO's standard evaluation (p0, references only, initial states 0-49 of ENTRY's suites) and compares\n"
    "  each suite's success with the published figure; --quick plays 2 initial states per task (inconclusive).\n"
    "  `conflictbench list` names the published entries of each model.\n"
)


def command(argv: list[str], plugins: Plugins) -> int:
    if argv[:1] in (["-h"], ["--help"]):
        print(USAGE, end="")
        return 0
    if any(arg in ("-m", "--multirun") for arg in argv):
        raise UserError("reproduce plays one run, not a sweep: drop -m")
    quick = "--quick" in argv
    argv, declared = take_declaration([arg for arg in argv if arg != "--quick"], plugins)
    if declared is None:
        raise UserError(f"reproduce needs {KEY}=<entry>: which published checkpoint this is (`conflictbench list`)")
    model = next((a.partition("=")[2] for a in argv if a.partition("=")[0].lstrip("+") == "model"), None)
    entry = check_declaration(declared, model or run.default_model(), plugins)
    defaults = [
        "prompt=p0",
        "run.cases_per_cell=0",  # references only: the original instructions
        f"run.libero_suites=[{','.join(entry.success)}]",
        f"run.init_states={QUICK_INIT_STATES if quick else INIT_STATES_PER_TASK}",
    ]

    def finish(store, episode_ids: list[str]) -> None:
        from conflictbench.report.from_store import light_records
        from conflictbench.report.reproduce import render, suite_rows, write_report

        rows = suite_rows(light_records(store, episode_ids), entry)
        sys.stdout.write(render(rows, entry))
        md, _ = write_report(rows, entry, store.root / "report")
        print(f"conflictbench: written to {md} and .csv; `conflictbench view {store.root}` shows the episodes",
              file=sys.stderr)  # fmt: skip

    return run.play([*defaults, *argv], plugins, declared=declared, finish=finish)
