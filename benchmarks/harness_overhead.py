"""Harness overhead: conflictbench's runner against a bare LIBERO loop, same policy, same steps.

Both sides play the same episodes (a base task, several initial states, the no-op policy for the
suite's full step budget): the bare loop in this process with one env, exactly as a minimal native
client would (seed, reset, set the initial state, 10 warm-up no-ops, step until done or the
budget), and the runner with one worker process, observation and action messages, the success
check, recording and an atomic Parquet write per episode. Rounds alternate the two sides so that
drift in machine load hits both. Goal: ratio <= 1.05.

    .venv/bin/python benchmarks/harness_overhead.py [--rounds 3] [--episodes 3] [--task libero_goal:0]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import numpy as np


def bare_loop(suite: str, task_id: int, states: list[int], steps: int) -> float:
    from conflictbench.sim.libero_env import EnvSettings, configure_process, make_env
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states

    settings = EnvSettings(needs_images=False)
    configure_process(settings)
    start = time.perf_counter()
    env = make_env(base_task(suite, task_id).bddl_path, settings)
    init_states = load_init_states(suite, task_id)
    noop = np.array([0, 0, 0, 0, 0, 0, -1.0])
    for state in states:
        env.seed(7)
        env.reset()
        env.set_init_state(init_states[state])
        for _ in range(10):
            env.step(noop)
        for _ in range(steps):
            _, _, done, _ = env.step(noop)
            if done:
                break
    env.close()
    return time.perf_counter() - start


def harness(suite: str, task_id: int, states: list[int]) -> float:
    import conflictbench
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore
    from conflictbench.tasks.libero.base_tasks import base_task

    plugins = conflictbench.plugins()
    spec = plugins.policy("noop")
    language = base_task(suite, task_id).language
    plan = [EpisodeSpec(suite, task_id, s, "p0", language) for s in states]
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        result = Runner(plugins, spec, None, store=EpisodeStore(tmp), workers=1, progress=False).run(plan)
        elapsed = time.perf_counter() - start
    assert result.played == len(states) and result.errors == 0
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--task", default="libero_goal:0")
    args = parser.parse_args()
    suite, task_id = args.task.split(":")
    from conflictbench.core import DEFAULT_MAX_STEPS

    states, steps = list(range(args.episodes)), DEFAULT_MAX_STEPS[suite]
    bare, ours = [], []
    for r in range(args.rounds):
        bare.append(bare_loop(suite, int(task_id), states, steps))
        ours.append(harness(suite, int(task_id), states))
        print(f"round {r + 1}: bare {bare[-1]:.1f} s, harness {ours[-1]:.1f} s, ratio {ours[-1] / bare[-1]:.3f}")
    b, h = statistics.median(bare), statistics.median(ours)
    per_step = len(states) * (steps + 10)
    print(
        f"\n{len(states)} episodes x {steps} steps of {suite} task {task_id}, {args.rounds} rounds, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(f"bare LIBERO loop : {b:.1f} s  ({per_step / b:.1f} env steps/s)")
    print(f"conflictbench    : {h:.1f} s  ({per_step / h:.1f} env steps/s)")
    print(f"ratio (median)   : {h / b:.3f}   goal <= 1.05")


if __name__ == "__main__":
    main()
