"""Make the goldens ``conflictbench doctor`` replays, for the stack of the Python that runs this script.

Plays one reference episode per LIBERO suite with the built-in ``scripted`` expert through the real runner (into a
temporary store), replays each with and without cameras as ``doctor`` does, checks that both replays retrace the
runner's path exactly and are solved at its last step, and writes conflictbench/doctor/goldens/<stack key>/: the
episodes' actions, paths and success steps, and frames of both cameras at three states, labelled with the renderer
family that made them. Run it once in each pinned environment (CPU, Mesa's llvmpipe: the reference renderer):

    MUJOCO_GL=egl .venv/bin/python scripts/make_goldens.py
    MUJOCO_GL=egl .venv312/bin/python scripts/make_goldens.py
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

import conflictbench
from conflictbench.doctor import goldens as golden_files
from conflictbench.doctor.replaying import DoctorJob, play_both_ways
from conflictbench.sim.replay import path_deviation

#: One task per LIBERO suite that the expert solves from initial state 0 in few steps (a short doctor), chosen from
#: a trial of two tasks per suite (steps on MuJoCo 2.3.7: spatial 0: 113, object 1: 126, goal 0: 170, 10 0: 304).
EPISODES = (("libero_spatial", 0, 0), ("libero_object", 1, 0), ("libero_goal", 0, 0), ("libero_10", 0, 0))
IMAGE_SIZE = 256  # the size policies see


def play_references(store_dir: Path, workers: int):
    from conflictbench.core.plugins import Plugins
    from conflictbench.sim.plan import EpisodeSpec
    from conflictbench.sim.runner import Runner
    from conflictbench.store import EpisodeStore
    from conflictbench.tasks.libero.base_tasks import base_task

    plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False)
    spec = plugins.policy("scripted")
    plan = [EpisodeSpec(suite, task, state, "p0", base_task(suite, task).language) for suite, task, state in EPISODES]
    store = EpisodeStore(store_dir)
    Runner(plugins, spec, spec.make_config(), store=store, workers=workers, progress=False).run(plan)
    records = {(r.suite, r.task_id, r.init_state): r for r in store.records()}
    return [records[episode] for episode in EPISODES]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="the goldens root (default: the package's conflictbench/doctor/goldens)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    from conflictbench.core.policy import DEFAULT_WARMUP_STEPS

    with tempfile.TemporaryDirectory() as store_dir:
        records = play_references(Path(store_dir), args.workers)
    episodes, jobs = [], []
    for r in records:
        if not r.success or r.error:
            sys.exit(f"the expert did not solve {r.suite} {r.task_id} state {r.init_state} ({r.error}): pick another")
        name = f"{r.suite}-{r.task_id}-{r.init_state}"
        warmup = DEFAULT_WARMUP_STEPS if r.warmup_steps is None else int(r.warmup_steps)
        frames = (0, int(r.steps) // 2, int(r.steps))
        episodes.append(golden_files.GoldenEpisode(name, r.suite, int(r.task_id), int(r.init_state), int(r.seed),
                                                   warmup, int(r.steps), frames))  # fmt: skip
        jobs.append(DoctorJob(episodes[-1], np.asarray(r.actions, dtype=np.float64)))
    blind, seeing = play_both_ways(jobs, IMAGE_SIZE)
    for record, job, *replays in zip(records, jobs, blind.replays, seeing.replays):
        for replayed in replays:
            deviation = None if replayed.path is None else path_deviation(replayed.path, record.eef_pos)
            if deviation != 0.0 or replayed.success_state != record.steps:
                sys.exit(f"{job.episode.name} {'with' if replayed.cameras else 'without'} cameras does not replay the "
                         f"runner's episode (deviation {deviation}, solved at {replayed.success_state} of "
                         f"{record.steps}; {replayed.error}): no goldens written")  # fmt: skip
    stack = seeing.stack
    key = golden_files.this_stack_key(stack)
    family = golden_files.renderer_family(stack.get("gl_vendor", ""), stack.get("gl_renderer", ""))
    root = Path(args.out) if args.out else golden_files.GOLDENS_ROOT
    goldens = golden_files.Goldens(
        folder=root / key,
        stack_key=key,
        stack=stack,
        renderer_family=family,
        image_size=IMAGE_SIZE,
        episodes=episodes,
        actions={job.episode.name: job.actions for job in jobs},
        eef_pos={job.episode.name: np.asarray(r.eef_pos, dtype=np.float64) for job, r in zip(jobs, records)},
    )
    frames = {(r.name, camera, state): frame for r in seeing.replays for (camera, state), frame in r.frames.items()}
    golden_files.write(goldens, frames)
    size = sum(p.stat().st_size for p in goldens.folder.rglob("*") if p.is_file())
    print(f"wrote {goldens.folder}: {len(episodes)} episodes, {len(frames)} frames ({family}), {size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
