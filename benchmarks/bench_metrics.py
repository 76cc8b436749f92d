"""Time the process measures at paper scale: the fast path against the plain implementation.

Paper scale is 8 models x 14,130 conflict pairs (113,040 pairs) of about 300 steps, each model
with 400 references (40 tasks x 5 initial states x 2 prompts) reused by about 35 conflicts.
The fast path (``evaluate_pairs``) runs on every pair, streamed in chunks; the plain
implementation (``conflictbench.metrics.plain``: full cost matrix, Python double loop) runs on a
few pairs and is extrapolated. Both are checked to agree on those pairs.

    .venv/bin/python benchmarks/bench_metrics.py                # full paper scale
    .venv/bin/python benchmarks/bench_metrics.py --pairs 20000  # a quicker run

Trajectories are synthetic but shaped like LIBERO rollouts: smooth reaches toward a target with
noise; conflicts either follow the reference with a time warp, stop early, or head elsewhere.
Data generation is not timed; nothing is cached between pairs, so reusing a pool of rollouts
costs the measured code nothing. The machine's load matters: other processes on the same cores
slow the wall-clock figure, so CPU time is printed too.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import time

import numpy as np

from conflictbench.core import EpisodeRecord
from conflictbench.metrics import evaluate_pairs, plain
from conflictbench.metrics.kernels import threads

PAPER_MODELS = 8
PAPER_PAIRS_PER_MODEL = 14_130
REFERENCES_PER_MODEL = 400


def reach(rng: np.random.Generator, start: np.ndarray, goal: np.ndarray, steps: int, pause: int = 0) -> np.ndarray:
    """A smooth reach from start to goal over ``steps`` actions, with noise; still after ``pause``."""
    s = np.linspace(0.0, 1.0, steps + 1)
    ease = (1 - np.cos(np.pi * np.clip(s * rng.uniform(0.8, 1.2), 0, 1))) / 2
    path = start + ease[:, None] * (goal - start) + np.cumsum(rng.normal(0, 0.002, (steps + 1, 3)), axis=0)
    if pause:
        path[pause:] = path[pause]
    return path


def rollout(rng, start, goal, target, steps, case, pause=0) -> EpisodeRecord:
    eef = reach(rng, start, goal, steps, pause)
    actions = np.zeros((steps, 7))
    actions[:, :3] = np.diff(eef, axis=0) * 20 + rng.normal(0, 0.01, (steps, 3))
    actions[:, 3:6] = rng.normal(0, 0.05, (steps, 3))
    actions[:, 6] = np.where(np.arange(steps) > steps // 2, 1.0, -1.0)
    targets = np.repeat(target[None, None, :], steps + 1, axis=0) + rng.normal(0, 0.001, (steps + 1, 1, 3))
    return EpisodeRecord(
        policy="bench",
        suite="libero_spatial",
        task_id=0,
        init_state=0,
        prompt="p0",
        instruction="x",
        case_id=case,
        eef_pos=eef,
        actions=actions,
        target_pos=targets,
        target_names=("akita_black_bowl_1",),
        success=bool(rng.random() < 0.5),
    )


def make_pool(rng, references: int, conflicts: int, steps: int):
    refs, cons, owner = [], [], []
    for _ in range(references):
        start = rng.normal([0.0, 0.0, 1.1], 0.02)
        target = start + rng.normal([0.1, 0.15, -0.25], 0.05)
        refs.append((start, target, rollout(rng, start, target, target, steps, None)))
    for c in range(conflicts):
        r = c % references
        start, target, _ = refs[r]
        kind = c % 3
        length = int(rng.integers(int(steps * 0.9), int(steps * 1.1) + 1))
        if kind == 0:  # failed persistence: the same reach, warped in time
            goal, pause = target + rng.normal(0, 0.02, 3), 0
        elif kind == 1:  # stops early
            goal, pause = target, int(rng.integers(5, 60))
        else:  # heads somewhere else
            goal, pause = start + rng.normal(0, 0.2, 3), 0
        cons.append(rollout(rng, start, goal, target, length, f"c{c}", pause))
        owner.append(r)
    return [rec for _, _, rec in refs], cons, owner


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=PAPER_MODELS * PAPER_PAIRS_PER_MODEL)
    parser.add_argument("--steps", type=int, default=300, help="actions per rollout (about)")
    parser.add_argument("--pool", type=int, default=4000, help="distinct conflict rollouts generated")
    parser.add_argument("--chunk", type=int, default=2048, help="pairs per evaluate_pairs call")
    parser.add_argument("--plain-pairs", type=int, default=6, help="pairs timed with the plain implementation")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    refs, cons, owner = make_pool(rng, REFERENCES_PER_MODEL, args.pool, args.steps)
    print(
        f"generated {len(refs)} references and {len(cons)} conflict rollouts of ~{args.steps} steps "
        f"in {time.perf_counter() - t0:.1f} s (not timed below)"
    )
    evaluate_pairs(refs[:2], cons[:2])  # compile or load the cached kernels before timing

    cells = 0
    wall = cpu = 0.0
    done = 0
    order = np.arange(len(cons))
    while done < args.pairs:
        n = min(args.chunk, args.pairs - done)
        picks = order[(done + np.arange(n)) % len(cons)]
        chunk_refs = [refs[owner[i]] for i in picks]
        chunk_cons = [cons[i] for i in picks]
        cells += sum(len(r.eef_pos) * len(c.eef_pos) for r, c in zip(chunk_refs, chunk_cons))
        w, c = time.perf_counter(), time.process_time()
        evaluate_pairs(chunk_refs, chunk_cons, chunk_size=args.chunk)  # per-pair rows, dropped
        wall += time.perf_counter() - w
        cpu += time.process_time() - c
        done += n
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024

    sample = list(range(args.plain_pairs))
    t = time.perf_counter()
    slow = [plain.pair_metrics(refs[owner[i]], cons[i]) for i in sample]
    plain_per_pair = (time.perf_counter() - t) / len(sample)
    fast = evaluate_pairs([refs[owner[i]] for i in sample], [cons[i] for i in sample])
    worst = max(abs(fast.at[j, k] - v) for j, row in enumerate(slow) for k, v in row.items() if v is not None)

    plain_total = plain_per_pair * args.pairs
    print(
        f"machine: {os.cpu_count()} cores, {threads()} compiled threads, load average "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())} (other processes slow the wall clock)"
    )
    print(
        f"fast path:  {args.pairs} pairs, {cells / 1e9:.2f} G DTW cells: {wall:.1f} s wall, {cpu:.1f} s CPU "
        f"({1e6 * wall / args.pairs:.0f} us/pair, {1e9 * cpu / cells:.2f} ns CPU/cell), peak RSS {rss:.0f} MiB"
    )
    print(
        f"plain:      {plain_per_pair:.3f} s/pair over {len(sample)} pairs -> {plain_total:.0f} s "
        f"({plain_total / 3600:.1f} h) extrapolated to {args.pairs} pairs"
    )
    print(f"ratio plain/fast (wall): {plain_total / wall:,.0f}x; largest |fast - plain| on the sample: {worst:.1e}")
    if not math.isfinite(worst) or worst > 1e-9:
        raise SystemExit("fast and plain results differ")


if __name__ == "__main__":
    main()
