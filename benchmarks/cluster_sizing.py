"""How long the paper's protocol takes on N machines: a sizing table from per-step costs measured here.

Measures the simulator's steps per second per core on this machine (the no-op policy, every core a
worker, each episode's own wall time, so worker start-up is left out), with the two 256-px cameras a
VLA sees (Mesa's software renderer) and without, then prints, for 1, 4 and 16 machines of
``--cores`` cores and one GPU policy server answering ``--policy-steps`` steps per second, the
episodes per hour and hours of the protocol, and what bounds them. The policy's rate is an input
(no GPU here); README's table states the figures it used and where they come from.

    .venv/bin/python benchmarks/cluster_sizing.py [--episodes 4] [--cores 32] [--policy-steps 50 400 inf]
    .venv/bin/python benchmarks/cluster_sizing.py --per-core 3.5 60   # skip measuring: cameras, none
"""

from __future__ import annotations

import argparse
import os
import tempfile

from workers_scaling import BenchPlugin, StillConfig

import conflictbench

#: The paper's protocol per model (ConflictVLA-Bench): rollouts and simulator steps (~300 per rollout).
PROTOCOL_ROLLOUTS = 14_530
PROTOCOL_STEPS = 4_400_000
#: One query's observation on the wire: two 256x256 RGB images and the state (uncompressed, as our clients send).
QUERY_BYTES = 2 * 256 * 256 * 3 + 1024


def steps_per_core(images: bool, episodes: int) -> float:
    from conflictbench.core.plugins import Plugins
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore
    from conflictbench.tasks.libero.base_tasks import base_task

    plan = [EpisodeSpec("libero_goal", 0, s, "p0", base_task("libero_goal", 0).language) for s in range(episodes)]
    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False, extra=[BenchPlugin()])
    spec = plugins.policy("bench-still")
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        store = EpisodeStore(tmp)
        Runner(plugins, spec, StillConfig(images), store=store, workers=cores, progress=False).run(plan)
        records = store.records()
    per_worker = sum(r.steps for r in records) / sum(r.wall_time_s for r in records)  # steps/s of one worker
    return per_worker  # one worker per core


def table(per_core: float, cores: int, policy_steps: list[float], chunk: int) -> str:
    lines = [
        "| machines | simulation (steps/s) | policy (steps/s) | network (MB/s to the policy) | episodes/hour "
        "| hours for the protocol | bound by |",
        "| ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for machines in (1, 4, 16):
        sim = per_core * cores * machines
        for policy in policy_steps:
            rate = min(sim, policy)
            megabytes = rate / chunk * QUERY_BYTES / 1e6
            hours = PROTOCOL_STEPS / rate / 3600
            per_hour = PROTOCOL_ROLLOUTS / hours
            bound = "simulation" if sim < policy else "policy"
            cells = [f"{machines}", f"{sim:,.0f}", f"{policy:,.0f}", f"{megabytes:,.0f}", f"{per_hour:,.0f}"]
            lines.append("| " + " | ".join([*cells, f"{hours:,.1f}", bound]) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--cores", type=int, default=32, help="cores per simulation machine")
    parser.add_argument("--policy-steps", type=float, nargs="+", default=[50.0, 400.0, float("inf")])
    parser.add_argument("--chunk", type=int, default=5, help="steps executed per policy query (pi0 on LIBERO: 5)")
    parser.add_argument("--per-core", type=float, nargs=2, metavar=("CAMERAS", "NONE"))
    args = parser.parse_args()
    if args.per_core:
        cameras, none = args.per_core
    else:
        cameras, none = steps_per_core(True, args.episodes), steps_per_core(False, args.episodes)
        print(
            f"measured here ({os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f}): "
            f"{cameras:.1f} steps/s per core with two 256-px cameras, {none:.1f} without\n"
        )
    # The cameras render only where the policy looks: once per chunk; physics every step.
    physics_s, render_s = 1 / none, 1 / cameras - 1 / none
    per_core = 1 / (physics_s + render_s / args.chunk)
    print(
        f"a step: {1e3 * physics_s:.0f} ms physics, {1e3 * render_s:.0f} ms rendering every {args.chunk}th step "
        f"-> {per_core:.1f} steps/s per core; {args.cores}-core machines:\n"
    )
    print(table(per_core, args.cores, args.policy_steps, args.chunk))


if __name__ == "__main__":
    main()
