"""Episodes per hour: conflictbench's runner against a bare openpi-style LIBERO client, same server, same episodes.

    .venv/bin/python plugins/pi0/benchmarks/throughput.py --out /tmp/pi0-throughput.json [--episodes 4] [--steps 100]
        [--max-batch N] [--server-threads 1] [--checkpoint DIR --hf-home HOME]

Run from the repository root with the simulator's environment; the model environment (``.venv/models/pi0``)
must exist. The script builds a tiny random-weight pi0.5 (``tests/tiny/build.py``; or reuse one with
``--checkpoint DIR --hf-home HOME``), starts ONE ``conflictbench-pi0 serve`` for it (one torch thread) and
plays the same reference episodes of libero_spatial (tasks 0, 0, 1, 1, ... with init states 0, 1), each with
the same step budget, three ways, one after the other, each in its own process:

- ``bare``: the loop of openpi's ``examples/libero/main.py`` written from its facts: ``OffScreenRenderEnv``
  256x256 with both cameras (so every step renders), ``env.seed(7)``, reset, ``set_init_state``, 10 no-op
  steps, then a request through openpi-client's ``WebsocketClientPolicy`` every 5th step (images rotated and
  ``resize_with_pad`` to 224), its first 5 actions executed;
- ``conflictbench-1`` and ``conflictbench-2``: ``Runner`` with ``model=pi05 model.server=URL
  model.max_steps=STEPS`` and 1 or 2 simulator workers, a fresh store each.

It prints a Markdown table (episodes/hour, ratios to the bare loop, where the time went, peak memory of the
client side and of the server, the server's batch sizes) and writes it all as JSON to ``--out``. Figures are
ratios on one machine, not absolute claims: the tiny model's calls cost what a CPU makes of a model of a million
parameters, not what a real checkpoint on a GPU costs.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

# Siblings of this script (its folder is on sys.path when it runs, in spawned workers too).
from episode_loops import PROBE_STEPS, REPLAN_STEPS, SUITE, WARMUP_STEPS, play_bare, play_conflictbench
from process_sampling import ProcessSampler, peak_rss_kib

PLUGIN_ROOT = Path(__file__).resolve().parents[1]
TINY_DIR = PLUGIN_ROOT / "tests" / "tiny"
MODEL_PYTHON = Path(sys.prefix) / "models" / "pi0" / "bin" / "python"
VARIANTS = {"bare": 0, "conflictbench-1": 1, "conflictbench-2": 2}
#: Every process that loads the tiny checkpoint needs these (see tests/tiny/build.py).
MODEL_ENV = {"HF_HUB_OFFLINE": "1", "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16", "OMP_NUM_THREADS": "1"}


def build_checkpoint(folder: Path, hf_home: Path) -> float:
    env = {**os.environ, **MODEL_ENV, "PYTHONPATH": str(TINY_DIR / "patches")}
    argv = [str(MODEL_PYTHON), str(TINY_DIR / "build.py"), "--policy", "pi05", "--out", str(folder)]
    started = time.perf_counter()
    subprocess.run([*argv, "--hf-home", str(hf_home)], env=env, check=True, capture_output=True, text=True)
    return time.perf_counter() - started


def start_server(checkpoint: Path, hf_home: Path, threads: int, max_batch: int | None):
    from conflictbench import ServerProcess, free_port

    port = free_port()
    argv = [str(MODEL_PYTHON), "-m", "conflictbench_pi0", "serve", "--policy", "pi05", "--checkpoint", str(checkpoint),
            "--host", "127.0.0.1", "--port", str(port), "--threads", str(threads)]  # fmt: skip
    if max_batch is not None:
        argv += ["--max-batch", str(max_batch)]
    python_path = os.pathsep.join([str(TINY_DIR / "patches"), str(PLUGIN_ROOT)])
    env = {**MODEL_ENV, "HF_HOME": str(hf_home), "PYTHONPATH": python_path}
    server = ServerProcess(argv, name="pi0-throughput", health_url=f"http://127.0.0.1:{port}/healthz", env=env)
    started = time.perf_counter()
    server.start()
    return server, f"ws://127.0.0.1:{port}", time.perf_counter() - started


def run_variant(name: str, url: str, args: argparse.Namespace, server_pid: int, scratch: Path) -> dict:
    result_file = scratch / f"{name}.json"
    argv = [sys.executable, __file__, "--variant", name, "--url", url, "--episodes", str(args.episodes),
            "--steps", str(args.steps), "--result", str(result_file)]  # fmt: skip
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    print(f"throughput: playing {name} ...", file=sys.stderr, flush=True)
    process = subprocess.Popen(argv, env=env, stdin=subprocess.DEVNULL)
    sampler = ProcessSampler(process.pid, server_pid)
    code = process.wait()
    peaks, load = sampler.stop()
    if code != 0:
        raise SystemExit(f"throughput: the {name} run failed with exit code {code}")
    measured = json.loads(result_file.read_text())
    return {**measured, **summarize(measured, args.episodes), "memory_kib": peaks, "load_average_1min": load}


def summarize(measured: dict, count: int) -> dict:
    calls = measured["server_timing"]
    infer_ms = [t["infer_ms"] for t in calls if "infer_ms" in t]
    steps = sum(e["steps"] for e in measured["episodes"])
    return {
        "episodes_per_hour": count / measured["wall_s"] * 3600,
        "policy_steps": steps,
        "successes": sum(e["success"] for e in measured["episodes"]),
        "model_calls": len(calls),
        "server_infer_ms_mean": statistics.fmean(infer_ms) if infer_ms else None,
        "batch_sizes": dict(sorted(Counter(t.get("batch_size") for t in calls).items(), key=lambda kv: str(kv[0]))),
    }


def markdown(report: dict) -> str:
    variants, bare = report["variants"], report["variants"]["bare"]
    rows = [
        "| run | workers | episodes | policy steps | wall s | episodes/h | vs bare | model calls | server ms/call "
        "| batch sizes (replies) | client peak RSS / PSS MiB (processes) | server RSS MiB | load avg (mean/max) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, v in variants.items():
        mem, load = v["memory_kib"], v["load_average_1min"]
        rows.append(
            f"| {name} | {VARIANTS[name] or '-'} | {len(v['episodes'])} | {v['policy_steps']} | {v['wall_s']:.1f} "
            f"| {v['episodes_per_hour']:.0f} | {v['episodes_per_hour'] / bare['episodes_per_hour']:.2f}x "
            f"| {v['model_calls']} | {v['server_infer_ms_mean'] or 0:.0f} | {v['batch_sizes']} "
            f"| {mem['client_rss'] / 1024:.0f} / {mem['client_pss'] / 1024:.0f} ({mem['client_processes']}) "
            f"| {mem['server_rss'] / 1024:.0f} | {load['mean']:.1f}/{load['max']:.1f} |"
        )
    spent, probe = bare["spent"], bare["probe"]
    lines = [
        "",
        f"Scaling 1 -> 2 workers (with images): {report['ratios']['workers_2_over_1']:.2f}x. The machine's 1-minute "
        f"load average is in the last column: on {report['machine']['cpus']} CPUs, anything above what a run "
        "itself adds (about 2) is another job slowing it down.",
        f"One env.step: {probe['rendered_step_s'] * 1000:.0f} ms rendering both 256-px cameras, "
        f"{probe['blind_step_s'] * 1000:.0f} ms without (probed in the bare process, {PROBE_STEPS} steps each).",
        f"bare, where the time went: env.step {spent['step_s']:.1f} s (every step rendered), round trips "
        f"{spent['infer_s']:.1f} s ({spent['infer_s'] / max(bare['model_calls'], 1) * 1000:.0f} ms/call), env builds "
        f"{spent['env_build_s']:.1f} s, resets + init states {spent['reset_s']:.1f} s, image preprocessing "
        f"{spent['preprocess_s']:.1f} s; the rest is imports and connecting.",
    ]
    for name in ("conflictbench-1", "conflictbench-2"):
        v = variants[name]
        sim = sum(e["sim_s"] or 0 for e in v["episodes"])
        waiting = sum(e["wall_s"] - (e["sim_s"] or 0) for e in v["episodes"])
        lines.append(
            f"{name}, summed over its episodes: simulation {sim:.1f} s (env builds, resets, steps; cameras rendered "
            f"only for the observation a query sends), waiting for the policy {waiting:.1f} s; the run's wall "
            f"{v['wall_s']:.1f} s includes starting {VARIANTS[name]} worker process(es)."
        )
    server, build_s = report["server"], report["checkpoint_build_s"]
    build = "reused" if build_s is None else f"built in {build_s:.1f} s"
    lines.append(
        f"Server: ready in {server['startup_s']:.1f} s, peak RSS since start {server['peak_rss_kib'] / 1024:.0f} MiB "
        f"(torch {server['threads']} thread(s); max_batch {server['metadata'].get('max_batch', '?')}, fixed_shape "
        f"{server['metadata'].get('fixed_shape', '?')}); tiny checkpoint {build}."
    )
    return "\n".join(rows + lines)


def orchestrate(args: argparse.Namespace) -> dict:
    if not MODEL_PYTHON.exists():
        raise SystemExit(f"throughput: no pi0 model environment at {MODEL_PYTHON} (scripts/setup.sh --models pi0)")
    with tempfile.TemporaryDirectory(prefix="pi0-throughput-") as scratch_dir:
        scratch = Path(scratch_dir)
        build_s = None
        if args.checkpoint:
            checkpoint, hf_home = Path(args.checkpoint), Path(args.hf_home)
        else:
            checkpoint, hf_home = scratch / "pi05", scratch / "hf-home"
            print("throughput: building a tiny pi0.5 ...", file=sys.stderr, flush=True)
            build_s = build_checkpoint(checkpoint, hf_home)
        server, url, startup_s = start_server(checkpoint, hf_home, args.server_threads, args.max_batch)
        try:
            variants = {name: run_variant(name, url, args, server.process.pid, scratch) for name in VARIANTS}
            server_peak = peak_rss_kib(server.process.pid)
        finally:
            server.stop()
    rate = {name: v["episodes_per_hour"] for name, v in variants.items()}
    return {
        "settings": {
            "episodes": args.episodes,
            "steps": args.steps,
            "suite": SUITE,
            "replan_steps": REPLAN_STEPS,
            "warmup_steps": WARMUP_STEPS,
            "server_threads": args.server_threads,
        },  # fmt: skip
        "machine": {
            "cpus": os.cpu_count(),
            "mujoco_gl": os.environ.get("MUJOCO_GL", "egl"),
            "lp_num_threads": os.environ.get("LP_NUM_THREADS"),
        },  # fmt: skip
        "checkpoint_build_s": build_s,
        "server": {
            "startup_s": startup_s,
            "peak_rss_kib": server_peak,
            "threads": args.server_threads,
            "metadata": variants["bare"]["server_metadata"],
        },  # fmt: skip
        "variants": variants,
        "ratios": {
            "conflictbench_1_over_bare": rate["conflictbench-1"] / rate["bare"],
            "conflictbench_2_over_bare": rate["conflictbench-2"] / rate["bare"],
            "workers_2_over_1": rate["conflictbench-2"] / rate["conflictbench-1"],
        },
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, help="write the measurements here as JSON")
    parser.add_argument("--episodes", type=int, default=4, help="episodes per run (default: %(default)s)")
    parser.add_argument("--steps", type=int, default=100, help="policy steps per episode (default: %(default)s)")
    parser.add_argument("--checkpoint", help="reuse a tiny pi05 checkpoint folder (needs --hf-home)")
    parser.add_argument("--hf-home", help="the HF_HOME its build filled")
    parser.add_argument("--server-threads", type=int, default=1, help="torch threads of the server (default: 1)")
    parser.add_argument("--max-batch", type=int, default=2, help="the server's --max-batch (default: 2)")
    parser.add_argument("--variant", choices=sorted(VARIANTS), help=argparse.SUPPRESS)  # one run, in a child
    parser.add_argument("--url", help=argparse.SUPPRESS)
    parser.add_argument("--result", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.episodes < 1 or args.steps < 1 or bool(args.checkpoint) != bool(args.hf_home):
        parser.error("--episodes and --steps must be >= 1; --checkpoint and --hf-home go together")
    if args.variant:
        if args.variant == "bare":
            measured = play_bare(args.url, args.episodes, args.steps)
        else:
            measured = play_conflictbench(args.url, args.episodes, args.steps, VARIANTS[args.variant])
        args.result.write_text(json.dumps(measured))
        return 0
    if args.out is None:
        parser.error("--out FILE is required")
    report = orchestrate(args)
    args.out.write_text(json.dumps(report, indent=2))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
