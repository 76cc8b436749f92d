"""Episodes per hour: conflictbench's runner against a bare openpi-style LIBERO client, same server, same episodes.

    .venv/bin/python plugins/pi0/benchmarks/throughput.py --out /tmp/pi0-throughput.json [--episodes 4] [--steps 100]

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
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

PLUGIN_ROOT = Path(__file__).resolve().parents[1]
TINY_DIR = PLUGIN_ROOT / "tests" / "tiny"
MODEL_PYTHON = Path(sys.prefix) / "models" / "pi0" / "bin" / "python"
SUITE, TASKS_IN_SUITE, INIT_STATES_PER_TASK, SEED = "libero_spatial", 10, 2, 7
#: Steps timed per camera setting by the bare run's probe of the step cost.
PROBE_STEPS = 20
WARMUP_STEPS, REPLAN_STEPS, IMAGE_SIZE, RENDER_SIZE = 10, 5, 224, 256
NOOP_ACTION = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]
CHECKPOINT_NAME = "tiny-pi05"
VARIANTS = {"bare": 0, "conflictbench-1": 1, "conflictbench-2": 2}
#: Every process that loads the tiny checkpoint needs these (see tests/tiny/build.py).
MODEL_ENV = {"HF_HUB_OFFLINE": "1", "ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16", "OMP_NUM_THREADS": "1"}


def episodes(count: int) -> list[tuple[int, int]]:
    """(task_id, init_state) of the benchmark's episodes: two init states per task, as a run plays several."""
    per_task = INIT_STATES_PER_TASK
    return [
        ((i // per_task) % TASKS_IN_SUITE, i % per_task + per_task * (i // (per_task * TASKS_IN_SUITE)))
        for i in range(count)
    ]


# -- memory: /proc, sampled (psutil is in neither environment) ----------------------------------------------------


def _process_tree(root: int) -> list[int]:
    children: dict[int, list[int]] = defaultdict(list)
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as stat:
                    ppid = int(stat.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children[ppid].append(int(entry))
    tree, todo = [], [root]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo.extend(children.get(pid, ()))
    return tree


def _memory_kib(pid: int, fields: tuple[str, ...] = ("Rss:", "Pss:")) -> dict[str, int]:
    """RSS and PSS (shared pages divided among their users, so sums over processes stay honest)."""
    found = {}
    try:
        with open(f"/proc/{pid}/smaps_rollup") as rollup:
            for line in rollup:
                name, value, *_ = line.split()
                if name in fields:
                    found[name.rstrip(":").lower()] = int(value)
    except (OSError, ValueError):
        pass
    return found


def peak_rss_kib(pid: int) -> int:
    """The kernel's high-water mark of ``pid``'s resident memory (VmHWM), since it started."""
    with open(f"/proc/{pid}/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM:"))


class MemorySampler:
    """Peak summed RSS/PSS of a process and all its descendants, and of the server, sampled every 0.25 s."""

    def __init__(self, client_root: int, server_pid: int):
        self.client_root, self.server_pid = client_root, server_pid
        self.peaks = {"client_rss": 0, "client_pss": 0, "server_rss": 0, "client_processes": 0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.25):
            tree = _process_tree(self.client_root)
            sizes = [_memory_kib(pid) for pid in tree]
            self.peaks["client_rss"] = max(self.peaks["client_rss"], sum(s.get("rss", 0) for s in sizes))
            self.peaks["client_pss"] = max(self.peaks["client_pss"], sum(s.get("pss", 0) for s in sizes))
            self.peaks["client_processes"] = max(self.peaks["client_processes"], sum(1 for s in sizes if s))
            server = _memory_kib(self.server_pid, ("Rss:",)).get("rss", 0)
            self.peaks["server_rss"] = max(self.peaks["server_rss"], server)

    def stop(self) -> dict[str, int]:
        self._stop.set()
        self._thread.join()
        return self.peaks


# -- the variants, each in its own process --------------------------------------------------------------------------


def play_bare(url: str, count: int, steps: int) -> dict:
    """openpi's LIBERO client loop (examples/libero/main.py), from its facts; every step renders both cameras."""
    import collections
    import warnings

    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ["PYOPENGL_PLATFORM"] = os.environ["MUJOCO_GL"]
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states, prepare_libero_import

    started = time.perf_counter()
    prepare_libero_import()
    import numpy as np
    from libero.libero.envs import OffScreenRenderEnv
    from openpi_client import image_tools
    from openpi_client.websocket_client_policy import WebsocketClientPolicy
    from robosuite.utils.transform_utils import quat2axisangle

    # openpi-client connects the way websockets 17 deprecates (harmless); after LIBERO's import, which
    # puts its own DeprecationWarning filter first.
    warnings.filterwarnings("ignore", message=r"connect\(\) must be used as a context manager")

    host, port = url.removeprefix("ws://").rsplit(":", 1)
    client = WebsocketClientPolicy(host, int(port))
    timings, outcomes = [], []
    spent = {"env_build_s": 0.0, "reset_s": 0.0, "step_s": 0.0, "infer_s": 0.0, "preprocess_s": 0.0}
    by_task: dict[int, list[int]] = defaultdict(list)
    for task_id, init_state in episodes(count):
        by_task[task_id].append(init_state)
    for task_id, init_states in by_task.items():
        task = base_task(SUITE, task_id)
        clock = time.perf_counter()
        env = OffScreenRenderEnv(bddl_file_name=task.bddl_path, camera_heights=RENDER_SIZE, camera_widths=RENDER_SIZE)
        env.seed(SEED)
        spent["env_build_s"] += time.perf_counter() - clock
        states = load_init_states(SUITE, task_id)
        for init_state in init_states:
            episode_start = clock = time.perf_counter()
            env.reset()
            obs = env.set_init_state(states[init_state])
            spent["reset_s"] += time.perf_counter() - clock
            clock = time.perf_counter()
            for _ in range(WARMUP_STEPS):
                obs, _, _, _ = env.step(NOOP_ACTION)
            spent["step_s"] += time.perf_counter() - clock
            plan: collections.deque = collections.deque()
            done, played = False, 0
            while played < steps and not done:
                if not plan:
                    clock = time.perf_counter()
                    element = {
                        "observation/image": _letterboxed(obs["agentview_image"], image_tools),
                        "observation/wrist_image": _letterboxed(obs["robot0_eye_in_hand_image"], image_tools),
                        "observation/state": np.concatenate(
                            (obs["robot0_eef_pos"], quat2axisangle(obs["robot0_eef_quat"]), obs["robot0_gripper_qpos"])
                        ),
                        "prompt": str(task.language),
                    }
                    sent = time.perf_counter()
                    spent["preprocess_s"] += sent - clock
                    reply = client.infer(element)
                    spent["infer_s"] += time.perf_counter() - sent
                    timings.append(dict(reply.get("server_timing", {})))
                    plan.extend(reply["actions"][:REPLAN_STEPS])
                clock = time.perf_counter()
                obs, _, done, _ = env.step(plan.popleft().tolist())
                spent["step_s"] += time.perf_counter() - clock
                played += 1
            outcomes.append({"task_id": task_id, "init_state": init_state, "steps": played, "success": bool(done),
                             "wall_s": time.perf_counter() - episode_start})  # fmt: skip
        last_env = env
    wall_s = time.perf_counter() - started
    probe = probe_step_cost(last_env, states[init_state])  # after the clock stopped: not part of the run
    last_env.close()
    return {"wall_s": wall_s, "episodes": outcomes, "server_timing": timings, "spent": spent, "probe": probe}


def probe_step_cost(env, init_state) -> dict:
    """Seconds per env.step with the cameras rendered and with them skipped (conflictbench's CameraGate)."""
    from conflictbench.sim.libero_env import CameraGate

    env.reset()
    env.set_init_state(init_state)
    gate, cost = CameraGate(env), {}
    for rendered in (False, True):
        gate.set(rendered)
        clock = time.perf_counter()
        for _ in range(PROBE_STEPS):
            env.step(NOOP_ACTION)
        cost["rendered_step_s" if rendered else "blind_step_s"] = (time.perf_counter() - clock) / PROBE_STEPS
    return cost


def _letterboxed(image, image_tools):
    import numpy as np

    upright = np.ascontiguousarray(image[::-1, ::-1])
    return image_tools.convert_to_uint8(image_tools.resize_with_pad(upright, IMAGE_SIZE, IMAGE_SIZE))


def play_conflictbench(url: str, count: int, steps: int, workers: int) -> dict:
    """conflictbench's Runner with ``model=pi05`` against the running server; the server's timings recorded."""
    import dataclasses

    import conflictbench
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore
    from conflictbench.tasks.libero.base_tasks import base_task

    plugins = conflictbench.plugins()
    spec = plugins.policy("pi05")
    config = spec.make_config({"server": url, "checkpoint": CHECKPOINT_NAME, "max_steps": steps})
    timings: list[dict] = []

    def load_recording_timings(cfg):
        policy = spec.load(cfg)
        decode = policy.decode

        def decode_recording(reply, observation):  # called from request threads: list.append is atomic
            timings.append(dict(reply.get("server_timing", {})))
            return decode(reply, observation)

        policy.decode = decode_recording
        return policy

    plan = [
        EpisodeSpec(SUITE, task_id, init_state, "p0", base_task(SUITE, task_id).language)
        for task_id, init_state in episodes(count)
    ]
    records = []
    with tempfile.TemporaryDirectory(prefix="pi0-throughput-store-") as store_dir:
        runner = Runner(
            plugins,
            dataclasses.replace(spec, load=load_recording_timings),
            config,
            store=EpisodeStore(Path(store_dir)),
            workers=workers,
            progress=False,
            on_episode=records.append,
        )
        started = time.perf_counter()
        result = runner.run(plan)
        wall_s = time.perf_counter() - started
    if result.played != count or result.errors:
        raise RuntimeError(f"conflictbench played {result.played} of {count} episodes, {result.errors} with errors")
    outcomes = [
        {"task_id": r.task_id, "init_state": r.init_state, "steps": r.steps, "success": r.success,
         "wall_s": r.wall_time_s, "sim_s": r.sim_time_s, "prompt_is_task_language": r.prompt_text == r.base_instruction}
        for r in records
    ]  # fmt: skip
    if not all(e["prompt_is_task_language"] for e in outcomes):
        raise RuntimeError("the runner sent other prompts than the tasks' language: not the bare loop's episodes")
    return {"wall_s": wall_s, "episodes": outcomes, "server_timing": timings}


# -- orchestration ----------------------------------------------------------------------------------------------


def build_checkpoint(folder: Path, hf_home: Path) -> float:
    env = {**os.environ, **MODEL_ENV, "PYTHONPATH": str(TINY_DIR / "patches")}
    argv = [str(MODEL_PYTHON), str(TINY_DIR / "build.py"), "--policy", "pi05", "--out", str(folder)]
    started = time.perf_counter()
    subprocess.run([*argv, "--hf-home", str(hf_home)], env=env, check=True, capture_output=True, text=True)
    return time.perf_counter() - started


def start_server(checkpoint: Path, hf_home: Path, threads: int):
    from conflictbench import ServerProcess, free_port

    port = free_port()
    argv = [str(MODEL_PYTHON), "-m", "conflictbench_pi0", "serve", "--policy", "pi05", "--checkpoint", str(checkpoint),
            "--host", "127.0.0.1", "--port", str(port), "--threads", str(threads)]  # fmt: skip
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
    sampler = MemorySampler(process.pid, server_pid)
    code = process.wait()
    peaks = sampler.stop()
    if code != 0:
        raise SystemExit(f"throughput: the {name} run failed with exit code {code}")
    measured = json.loads(result_file.read_text())
    return {**measured, **summarize(measured, args.episodes), "memory_kib": peaks}


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
        "| batch sizes (replies) | client peak RSS / PSS MiB (processes) | server RSS MiB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, v in variants.items():
        mem = v["memory_kib"]
        rows.append(
            f"| {name} | {VARIANTS[name] or '-'} | {len(v['episodes'])} | {v['policy_steps']} | {v['wall_s']:.1f} "
            f"| {v['episodes_per_hour']:.0f} | {v['episodes_per_hour'] / bare['episodes_per_hour']:.2f}x "
            f"| {v['model_calls']} | {v['server_infer_ms_mean'] or 0:.0f} | {v['batch_sizes']} "
            f"| {mem['client_rss'] / 1024:.0f} / {mem['client_pss'] / 1024:.0f} ({mem['client_processes']}) "
            f"| {mem['server_rss'] / 1024:.0f} |"
        )
    spent, probe = bare["spent"], bare["probe"]
    lines = [
        "",
        f"Scaling 1 -> 2 workers (with images): {report['ratios']['workers_2_over_1']:.2f}x.",
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
        f"(torch {server['threads']} thread(s)); tiny checkpoint {build}."
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
        server, url, startup_s = start_server(checkpoint, hf_home, args.server_threads)
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
        "server": {"startup_s": startup_s, "peak_rss_kib": server_peak, "threads": args.server_threads},
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
