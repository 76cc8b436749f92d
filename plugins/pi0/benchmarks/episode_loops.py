"""The episodes the throughput benchmark plays, two ways, each run in its own process by ``throughput.py``.

``play_bare`` is openpi's LIBERO client loop (``examples/libero/main.py``) written from its facts, not copied;
``play_conflictbench`` is conflictbench's ``Runner`` with ``model=pi05`` against the same running server. Both
return the wall time, per-episode outcomes and the ``server_timing`` of every reply.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

SUITE, TASKS_IN_SUITE, INIT_STATES_PER_TASK, SEED = "libero_spatial", 10, 2, 7
#: Steps timed per camera setting by the bare run's probe of the step cost.
PROBE_STEPS = 20
WARMUP_STEPS, REPLAN_STEPS, IMAGE_SIZE, RENDER_SIZE = 10, 5, 224, 256
NOOP_ACTION = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]
CHECKPOINT_NAME = "tiny-pi05"


def episodes(count: int) -> list[tuple[int, int]]:
    """(task_id, init_state) of the benchmark's episodes: two init states per task, as a run plays several."""
    per_task = INIT_STATES_PER_TASK
    return [
        ((i // per_task) % TASKS_IN_SUITE, i % per_task + per_task * (i // (per_task * TASKS_IN_SUITE)))
        for i in range(count)
    ]


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
    measured = {"wall_s": wall_s, "episodes": outcomes, "server_timing": timings, "spent": spent, "probe": probe}
    return {**measured, "server_metadata": _plain(client.get_server_metadata())}


def _plain(metadata: dict) -> dict:
    """The server's metadata frame, JSON-ready (its scalars and strings; arrays and the like as text)."""
    return {
        str(k): v if isinstance(v, (str, int, float, bool, type(None), list)) else repr(v) for k, v in metadata.items()
    }


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
