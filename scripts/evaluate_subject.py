"""Does the learned subject meet its bar? Reference success at the evaluation initial states, and in libero_goal
(one scene, ten goals) the same episodes told another task's instruction or the words of their own shuffled.

    .venv/bin/python scripts/evaluate_subject.py [--weights W.npz] [--states 5] [--out DIR] [--workers 2]

Episodes go to an ordinary store (DIR, default results-subject-bar): a second call plays only what is missing.
Prints one table; ``--json`` writes the figures too.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import random
import sys
from collections import defaultdict
from pathlib import Path

from conflictbench import plugins as load_plugins
from conflictbench.core import LIBERO_SUITES
from conflictbench.sim.plan import EpisodeSpec
from conflictbench.sim.runner import Runner
from conflictbench.store import EpisodeStore
from conflictbench.tasks.libero.base_tasks import all_base_tasks

GOAL = "libero_goal"


def shuffled(text: str, seed: int) -> str:
    words = text.split()
    for attempt in range(100):  # a shuffle that leaves the words in place is no shuffle
        random.Random(seed * 1000 + attempt).shuffle(words)
        if words != text.split():
            break
    return " ".join(words)


def plan(states: list[int]) -> dict[str, list[EpisodeSpec]]:
    tasks = all_base_tasks(tuple(LIBERO_SUITES))
    goal = {t.task_id: t.language for t in tasks if t.suite == GOAL}
    references = [EpisodeSpec(t.suite, t.task_id, s, "p0", t.language) for t in tasks for s in states]
    goal_refs = [e for e in references if e.suite == GOAL]
    return {
        "reference": references,
        "other instruction": [
            dataclasses.replace(e, base_instruction=goal[(e.task_id + 1) % len(goal)]) for e in goal_refs
        ],
        "shuffled words": [
            dataclasses.replace(e, base_instruction=shuffled(e.base_instruction, e.task_id * 100 + e.init_state))
            for e in goal_refs
        ],
    }


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", default=None, help="a .npz from train-subject (default: the shipped weights)")
    p.add_argument("--states", type=int, default=5, help="evaluation initial states 0..N-1 (5)")
    p.add_argument("--out", type=Path, default=Path("results-subject-bar"))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--seed", type=int, default=0, help="model.seed: another sample of the gripper's draws")
    p.add_argument("--likelier-gripper", action="store_true", help="model.sample_gripper=false")
    args = p.parse_args(argv)

    plugins = load_plugins()
    spec = plugins.policy("subject")
    config = spec.make_config({"weights": args.weights, "seed": args.seed, "sample_gripper": not args.likelier_gripper})
    store = EpisodeStore(args.out)
    groups = plan(list(range(args.states)))
    every = [e for group in groups.values() for e in group]
    result = Runner(plugins, spec, config, store=store, workers=args.workers).run(every)
    group_of = {(e.suite, e.task_id, e.init_state, e.instruction): n for n, group in groups.items() for e in group}
    success, unscored = defaultdict(list), 0
    for record in store.records(result.episode_ids):  # this run's episodes (the store may hold other weights')
        name = group_of.get((record.suite, record.task_id, record.init_state, record.instruction))
        if name is None:
            continue
        if record.infrastructure_failed:  # the simulator's or the machine's failure, not the subject's
            unscored += 1
        else:  # an error of the policy itself counts as a failure, as in every report
            success[(name, record.suite)].append(record.success and not record.error)
    rows = {f"{name} / {suite}": (sum(v), len(v)) for (name, suite), v in sorted(success.items())}
    overall = [s for (name, _), v in success.items() if name == "reference" for s in v]
    rows["reference / all"] = (sum(overall), len(overall))
    for label, (ok, n) in rows.items():
        print(f"{label:40s} {ok:4d}/{n:<4d} {100 * ok / max(n, 1):5.1f} %")
    if unscored:
        print(f"{unscored} episode(s) not scored: an infrastructure error (play them again: the store keeps the rest)")
    if args.json:
        args.json.write_text(json.dumps({k: {"succeeded": a, "episodes": b} for k, (a, b) in rows.items()}, indent=2))
    return 0


if __name__ == "__main__":
    from conflictbench.core import UserError

    try:
        sys.exit(main(sys.argv[1:]))
    except UserError as exc:
        sys.exit(f"evaluate_subject: error: {exc}")
