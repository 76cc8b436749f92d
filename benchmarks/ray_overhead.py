"""What Ray costs one run: episodes per hour of ``run.backend=ray`` against the local pool, on this machine.

The same plan (no-op policy, a query every step: the worst case, a VLA's chunks ask less often) into
fresh stores, alternating local and ray runs side by side in one invocation. Ray is started once
before timing (on a cluster it already runs); its start is printed apart. Goal: ray / local <= 1.05.

    .venv/bin/python benchmarks/ray_overhead.py [--tasks 2] [--states 4] [--rounds 2] [--images]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from workers_scaling import play, reference_plan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="libero_goal")
    parser.add_argument("--tasks", type=int, default=2)
    parser.add_argument("--states", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--images", action="store_true")
    args = parser.parse_args()
    import logging

    import ray

    plan = reference_plan(args.suite, args.tasks, args.states)
    start = time.perf_counter()
    ray.init(num_cpus=os.cpu_count(), include_dashboard=False, logging_level=logging.WARNING)
    print(f"Ray started in {time.perf_counter() - start:.1f} s (not counted below)")
    times: dict[str, list[float]] = {"local": [], "ray": []}
    for _ in range(args.rounds):
        for backend in times:
            seconds = play(plan, 2, args.images, backend=backend)
            times[backend].append(seconds)
            print(f"{backend:>5}: {seconds:6.1f} s  ({3600 * len(plan) / seconds:.0f} episodes/h)")
    ray.shutdown()
    local, remote = statistics.mean(times["local"]), statistics.mean(times["ray"])
    print(
        f"\n{len(plan)} episodes of {args.suite} x {args.rounds} rounds, 2 workers, images={args.images}, "
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}"
    )
    print(f"wall time ray / local: {remote / local:.3f}   goal <= 1.05")


if __name__ == "__main__":
    main()
