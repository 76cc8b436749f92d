"""Success of the built-in `scripted` expert on the 40 LIBERO base tasks (reference rollouts).

Plays every base task from its first N fixed initial states (default 5: 200 episodes) with the
real runner into a store, so an interrupted run picks up where it stopped, then prints the
success table per LIBERO suite and every task below 80%. Goal (#3): >= 90% overall, no suite
below 80%. Not part of CI: about 15 s of simulation per episode on this machine.

    .venv/bin/python benchmarks/scripted_success.py [--states 5] [--workers 2] [--out results/scripted-success]
    .venv/bin/python benchmarks/scripted_success.py --tasks libero_goal:3,libero_10:0-4   # a subset
"""

from __future__ import annotations

import argparse
import os
from collections import defaultdict

import conflictbench
from conflictbench.tasks.libero.base_tasks import LIBERO_SUITES, base_task

TASKS_PER_SUITE = 10


def parse_tasks(text: str | None) -> list[tuple[str, int]]:
    """``libero_goal:3,libero_10:0-4`` -> [(suite, task_id), ...]; None: all 40."""
    if not text:
        return [(s, t) for s in LIBERO_SUITES for t in range(TASKS_PER_SUITE)]
    out = []
    for part in text.split(","):
        suite, _, ids = part.partition(":")
        if not ids:
            out += [(suite, t) for t in range(TASKS_PER_SUITE)]
            continue
        lo, _, hi = ids.partition("-")
        out += [(suite, t) for t in range(int(lo), int(hi or lo) + 1)]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--states", type=int, default=5, help="first N fixed initial states per task")
    parser.add_argument("--tasks", default=None, help="subset, e.g. libero_goal:3,libero_10:0-4")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="results/scripted-success")
    parser.add_argument("--model", default="scripted")
    args = parser.parse_args()

    from conflictbench.core.plugins import Plugins
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore

    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False)
    spec = plugins.policy(args.model)
    tasks = parse_tasks(args.tasks)
    plan = [
        EpisodeSpec(suite, t, s, "p0", base_task(suite, t).language) for suite, t in tasks for s in range(args.states)
    ]
    store = EpisodeStore(args.out)
    result = Runner(plugins, spec, spec.make_config(), store=store, workers=args.workers).run(plan)

    wanted = set(result.episode_ids)
    per_task: dict[tuple[str, int], dict[int, bool]] = defaultdict(dict)
    steps: list[int] = []
    errors: list[str] = []
    wall: list[float] = []
    for record in store.load([(eid, args.model) for eid in wanted]):
        wall.append(float(record.wall_time_s))
        per_task[(record.suite, record.task_id)][int(record.init_state)] = bool(record.success)
        steps.append(int(record.steps))
        if record.error:
            errors.append(f"{record.suite} {record.task_id} state {record.init_state}: {record.error}")

    print(f"\n{args.model}: {len(wanted)} episodes, first {args.states} initial states, {os.cpu_count()} cores")
    print("\n| LIBERO suite | successes | rate |\n| --- | ---: | ---: |")
    total = [0, 0]
    for suite in LIBERO_SUITES:
        runs = [ok for (s, _), oks in per_task.items() if s == suite for ok in oks.values()]
        if runs:
            print(f"| {suite} | {sum(runs)}/{len(runs)} | {100 * sum(runs) / len(runs):.0f}% |")
            total[0] += sum(runs)
            total[1] += len(runs)
    if total[1]:
        print(f"| all | {total[0]}/{total[1]} | {100 * total[0] / total[1]:.1f}% |")
    weak = [(k, oks) for k, oks in sorted(per_task.items()) if sum(oks.values()) < 0.8 * len(oks)]
    if weak:
        print("\nTasks below 80%:")
        for (suite, t), oks in weak:
            failed = sorted(i for i, ok in oks.items() if not ok)
            language = base_task(suite, t).language
            print(f"  {suite} {t} ({sum(oks.values())}/{len(oks)}, failed states {failed}): {language!r}")
    if steps:
        print(
            f"\nmean steps per episode: {sum(steps) / len(steps):.0f}, "
            f"mean simulation wall time: {sum(wall) / len(wall):.1f} s"
        )
    for line in errors:
        print("error:", line)


if __name__ == "__main__":
    main()
