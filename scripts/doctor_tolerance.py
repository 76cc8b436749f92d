"""What perturbing the physics does to the golden episodes: the measurements behind doctor's path tolerance.

Replays the goldens (camera-less: a camera env steps identically, which doctor checks) unperturbed and under each
perturbation, and prints per perturbation the largest end-effector path deviation from the goldens and how many
success steps changed. Run with the environment whose goldens to compare, or another's goldens (--goldens) to see
what another MuJoCo does to them:

    MUJOCO_GL=egl .venv/bin/python scripts/doctor_tolerance.py
    MUJOCO_GL=egl .venv312/bin/python scripts/doctor_tolerance.py --only none \
        --goldens conflictbench/doctor/goldens/py3.11-mujoco2.3.7
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
from concurrent.futures import ProcessPoolExecutor

from conflictbench.doctor import goldens as golden_files
from conflictbench.doctor.physics import TOLERANCE_M, compare_all
from conflictbench.doctor.replaying import parse_perturbations, play_group
from conflictbench.doctor.simulator import jobs_of
from conflictbench.sim.libero_env import EnvSettings

#: name -> the --perturb texts. LIBERO's scenes' solver defaults (printed from the model itself): 100 iterations,
#: tolerance 1e-8, timestep 0.002. A run's figures are beside doctor's TOLERANCE_M (conflictbench/doctor/physics.py).
PERTURBATIONS = {
    "none": [],
    "qpos_ulp=1": ["qpos_ulp=1"],
    "iterations=50": ["iterations=50"],
    "iterations=5": ["iterations=5"],
    "tolerance=1e-4": ["tolerance=1e-4"],
    "timestep=0.0021": ["timestep=0.0021"],
}


def solver_defaults(goldens) -> str:
    from conflictbench.sim import libero_env
    from conflictbench.tasks.libero.base_tasks import base_task

    libero_env.configure_process(EnvSettings(False))
    episode = goldens.episodes[0]
    env = libero_env.make_env(base_task(episode.suite, episode.task_id).bddl_path, EnvSettings(False))
    opt = env.sim.model._model.opt
    said = f"iterations {opt.iterations}, tolerance {opt.tolerance:g}, timestep {opt.timestep:g}"
    env.close()
    return said


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--goldens", help="one stack's goldens folder (default: this stack's, or the nearest)")
    parser.add_argument("--only", help="comma-separated names of the perturbations to run: " + ", ".join(PERTURBATIONS))
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    from conflictbench.sim.stack import stack_probe

    key = golden_files.this_stack_key(stack_probe(False))
    goldens, own = golden_files.choose(key, args.goldens)
    names = args.only.split(",") if args.only else list(PERTURBATIONS)
    jobs = jobs_of(goldens)
    context = mp.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=context) as executor:
        defaults = executor.submit(solver_defaults, goldens)
        futures = {
            name: executor.submit(play_group, jobs, EnvSettings(False), parse_perturbations(PERTURBATIONS[name]))
            for name in names
        }
        print(f"stack {key}, goldens {goldens.stack_key}; solver: {defaults.result()}; tolerance {TOLERANCE_M:g} m")
        print("| perturbation | max path deviation (m) | per episode (m) | success steps changed |")
        print("| --- | ---: | --- | --- |")
        for name, future in futures.items():
            comparisons = compare_all(future.result().replays, goldens)
            worst = max(c.deviation_m if c.deviation_m is not None else float("inf") for c in comparisons)
            each = ", ".join(f"{c.episode.removeprefix('libero_')} {c.deviation_m:.2g}" for c in comparisons)
            changed = [f"{c.episode}: {c.golden_success_state} -> {c.success_state}" for c in comparisons
                       if c.success_state != c.golden_success_state]  # fmt: skip
            print(f"| {name} | {worst:.3g} | {each} | {len(changed)}/{len(comparisons)} {'; '.join(changed)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
