"""Episodes per hour of the GR00T and VLA-JEPA clients: conflictbench's runner against a bare native loop.

    .venv/bin/python benchmarks/served_clients.py --model gr00t [--episodes 4] [--steps 96] [--out FILE]
    .venv/bin/python benchmarks/served_clients.py --model vla-jepa [--server ours]

For one model, starts the plugin's test stand-in of the upstream server (a numpy model that answers at once,
so what is measured is everything but the model), or with ``--server ours`` the plugin's own server
(``conflictbench-<model> serve``, ``--max-batch 2``, one torch thread) hosting the tests' tiny random-weight
checkpoint (built first, in the model environment: a real model call of a few tens of ms), and plays the same
reference episodes of libero_spatial (tasks 0, 0, 1, 1, ... at initial states 0, 1), each with the same step
budget, three ways, one after the other, each in its own process:

- ``bare``: the native client loop written from upstream's facts: ``OffScreenRenderEnv`` 256 x 256 with both
  cameras (every step renders), ``env.seed(7)``, reset, ``set_init_state``, the model's warm-up no-ops (GR00T
  none, VLA-JEPA 10), then a request through the plugin's own transport whenever the chunk runs out, with
  the model's processing (the plugin's ``processing`` module: the same steps upstream's client does);
- ``conflictbench-1`` and ``conflictbench-2``: ``Runner`` with ``model=... model.server=URL`` and one or two
  simulator workers (cameras rendered only where the policy looks), a fresh store each.

Prints a Markdown table (episodes/hour, ratio to the bare loop, peak RSS of the playing process and of its
largest worker) and writes it as JSON to ``--out``. Ratios on one machine; with the stand-in no model cost is in them.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUITE, SEED, NOOP = "libero_spatial", 7, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]
MODELS = {
    "gr00t": {"tests": ROOT / "plugins/gr00t/tests", "standin": "gr00t_standin", "warmup": 0,
              "module": "conflictbench_gr00t", "tiny": "tiny_groot.py", "env": "groot_model_env"},
    "vla-jepa": {"tests": ROOT / "plugins/vla_jepa/tests", "standin": "jepa_standin", "warmup": 10,
                 "module": "conflictbench_vla_jepa", "tiny": "tiny_jepa.py", "env": "jepa_model_env"},
}  # fmt: skip


def episodes(count: int) -> list[tuple[int, int]]:
    return [((i // 2) % 10, i % 2) for i in range(count)]


def settings(model: str, url: str, steps: int, scratch: Path, ours: bool = False) -> dict:
    base = {"server": url, "checkpoint": "stand-in", "max_steps": steps}
    if model == "vla-jepa" and not ours:  # our server sends the statistics
        sys.path.insert(0, str(MODELS[model]["tests"]))
        from jepa_standin import write_run

        base["stats"] = str(write_run(scratch / "run", window=7))
    return base


def play_bare(model: str, url: str, count: int, steps: int, scratch: Path, ours: bool) -> dict:
    import numpy as np

    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states, prepare_libero_import

    prepare_libero_import()
    from libero.libero.envs import OffScreenRenderEnv
    from robosuite.utils.transform_utils import quat2axisangle

    import conflictbench

    policy = conflictbench.plugins().policy(model)
    client = policy.load(policy.make_config(settings(model, url, steps, scratch, ours)))  # for encode/decode only
    transport = client.make_transport(url)
    transport.connect(10.0)
    started, outcomes, by_task = time.perf_counter(), [], {}
    for task_id, init_state in episodes(count):
        by_task.setdefault(task_id, []).append(init_state)
    for task_id, init_states in by_task.items():  # one env per task, seeded once, as upstream's loops do
        task = base_task(SUITE, task_id)
        env = OffScreenRenderEnv(bddl_file_name=task.bddl_path, camera_heights=256, camera_widths=256)
        env.seed(SEED)
        for init_state in init_states:
            env.reset()
            obs = env.set_init_state(load_init_states(SUITE, task_id)[init_state])
            for _ in range(MODELS[model]["warmup"]):
                obs, _, _, _ = env.step(NOOP)
            plan, done, played = [], False, 0
            while played < steps and not done:
                if not plan:
                    quat = obs["robot0_eef_quat"]
                    state = np.concatenate((obs["robot0_eef_pos"], quat2axisangle(quat), obs["robot0_gripper_qpos"]))
                    observation = conflictbench.Observation(
                        step=played, instruction=task.language, eef_pos=state[:3], eef_quat=quat,
                        gripper_qpos=state[6:], state=state, agentview_image=obs["agentview_image"],
                        wrist_image=obs["robot0_eye_in_hand_image"], episode_id=f"{task_id}/{init_state}",
                    )  # fmt: skip
                    reply = transport.exchange(client.encode(observation), 60.0)
                    plan = list(client.decode(reply, observation))
                obs, _, done, _ = env.step(plan.pop(0).tolist())
                played += 1
            outcomes.append({"task_id": task_id, "init_state": init_state, "steps": played})
        env.close()
    wall_s = time.perf_counter() - started
    transport.close()
    client.close()
    return {"wall_s": wall_s, "episodes": outcomes}


def play_conflictbench(model: str, url: str, count: int, steps: int, workers: int, scratch: Path, ours: bool) -> dict:
    import conflictbench
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore
    from conflictbench.tasks.libero.base_tasks import base_task

    plugins = conflictbench.plugins()
    spec = plugins.policy(model)
    config = spec.make_config(settings(model, url, steps, scratch, ours))
    plan = [EpisodeSpec(SUITE, t, s, "p0", base_task(SUITE, t).language) for t, s in episodes(count)]
    runner = Runner(plugins, spec, config, store=EpisodeStore(scratch / "store"), workers=workers, progress=False)
    started = time.perf_counter()
    result = runner.run(plan)
    wall_s = time.perf_counter() - started
    if result.played != count or result.errors:
        raise RuntimeError(f"conflictbench played {result.played} of {count} episodes, {result.errors} with errors")
    return {"wall_s": wall_s}


def start_ours(model: str, scratch: Path):
    """The plugin's own server for the tests' tiny checkpoint (built here), on a free port, ready."""
    from conflictbench import ServerProcess, free_port

    facts = MODELS[model]
    model_env = __import__(facts["env"])
    checkpoint = scratch / "tiny"
    subprocess.run([str(model_env.MODEL_PYTHON), str(facts["tests"] / facts["tiny"]), str(checkpoint)],
                   env=model_env.model_env(checkpoint), check=True, capture_output=True)  # fmt: skip
    port = free_port()
    scheme = "tcp" if model == "gr00t" else "ws"
    url = f"{scheme}://127.0.0.1:{port}"
    argv = [str(model_env.MODEL_PYTHON), "-m", facts["module"], "serve", "--policy", model, "--checkpoint",
            str(checkpoint), "--port", str(port), "--max-batch", "2", "--device", "cpu", "--threads", "1"]  # fmt: skip
    ready = None
    if model == "gr00t":
        from conflictbench.hosting.zeromq import answers_ping

        ready = lambda: answers_ping(url)  # noqa: E731
    server = ServerProcess(argv, name=f"{model}-tiny", health_url=f"http://127.0.0.1:{port}/healthz", ready=ready,
                           env=model_env.model_env(checkpoint), startup_timeout_s=300, log_dir=scratch)  # fmt: skip
    return server.start(), url


def variant_main(args: argparse.Namespace) -> None:
    """One variant in this process; prints its result as JSON on the last line."""
    scratch = Path(tempfile.mkdtemp(prefix="served-clients-"))
    if args.variant == "bare":
        result = play_bare(args.model, args.url, args.episodes, args.steps, scratch, args.server == "ours")
    else:
        workers = int(args.variant.rsplit("-", 1)[1])
        ours = args.server == "ours"
        result = play_conflictbench(args.model, args.url, args.episodes, args.steps, workers, scratch, ours)
    result["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result["worker_peak_rss_mib"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    print(json.dumps(result))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", choices=sorted(MODELS), required=True)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--steps", type=int, default=96)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--server", choices=["standin", "ours"], default="standin")
    parser.add_argument("--variant", help=argparse.SUPPRESS)
    parser.add_argument("--url", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.variant:
        variant_main(args)
        return 0
    sys.path.insert(0, str(MODELS[args.model]["tests"]))
    scratch = Path(tempfile.mkdtemp(prefix="served-clients-"))
    if args.server == "ours":
        server, url = start_ours(args.model, scratch)
    else:
        server, url = __import__(MODELS[args.model]["standin"]).start_standin(scratch)
    report = {"model": args.model, "server": args.server, "episodes": args.episodes, "steps": args.steps}
    report["variants"] = {}
    try:
        for variant in ("bare", "conflictbench-1", "conflictbench-2"):
            command = [sys.executable, __file__, "--model", args.model, "--episodes", str(args.episodes)]
            command += ["--steps", str(args.steps), "--variant", variant, "--url", url, "--server", args.server]
            done = subprocess.run(command, capture_output=True, text=True, check=True, cwd=scratch)
            report["variants"][variant] = json.loads(done.stdout.strip().splitlines()[-1])
    finally:
        server.stop()
    bare = report["variants"]["bare"]["wall_s"]
    lines = [
        f"{args.model}: {args.episodes} episodes x {args.steps} steps, "
        + ("our server, tiny model, max_batch 2" if args.server == "ours" else "stand-in server (no model cost)"),
        "",
        "| variant | wall s | episodes/hour | vs bare | peak RSS MiB (worker) |",
        "| --- | ---: | ---: | ---: | ---: |",
    ]
    for name, measured in report["variants"].items():
        rate = 3600 * args.episodes / measured["wall_s"]
        worker = "-" if name == "bare" else f"{measured['worker_peak_rss_mib']:.0f}"  # bare plays in-process
        measured["episodes_per_hour"], measured["speedup_vs_bare"] = rate, bare / measured["wall_s"]
        lines.append(
            f"| {name} | {measured['wall_s']:.1f} | {rate:.0f} | {bare / measured['wall_s']:.2f}x | "
            f"{measured['peak_rss_mib']:.0f} ({worker}) |"
        )
    print("\n".join(lines))
    if args.out:
        args.out.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
