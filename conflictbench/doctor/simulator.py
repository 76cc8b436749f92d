"""The simulator's checks: the stack, the physics and the rendering, from one replay of the goldens."""

from __future__ import annotations

import platform
import shutil
import subprocess

from . import goldens as golden_files
from .checks import Check
from .physics import TOLERANCE_M, compare_all, physics_check
from .rendering import compare_frames, rendering_check
from .replaying import DoctorJob, play_both_ways

VERSION_KEYS = ("mujoco_version", "robosuite_version", "libero_version", "numpy_version")


def jobs_of(goldens: golden_files.Goldens) -> list[DoctorJob]:
    return [DoctorJob(e, goldens.actions[e.name]) for e in goldens.episodes]


def gpu() -> str:
    """The GPU and its driver as ``nvidia-smi`` says (printed only: not part of any episode's provenance)."""
    if not shutil.which("nvidia-smi"):
        return "none found (no nvidia-smi on PATH)"
    try:
        said = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
                              capture_output=True, text=True, timeout=20, stdin=subprocess.DEVNULL)  # fmt: skip
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"nvidia-smi failed ({type(exc).__name__})"
    lines = [line.strip().replace(", ", " driver ") for line in said.stdout.splitlines() if line.strip()]
    return "; ".join(lines) if said.returncode == 0 and lines else f"nvidia-smi exited {said.returncode}"


def stack_check(stack: dict[str, str], goldens: golden_files.Goldens, family: str) -> Check:
    versions = ", ".join(f"{key.removesuffix('_version')} {stack.get(key, '?')}" for key in VERSION_KEYS)
    gl = (f"GL {stack.get('gl_backend', '?')}: {stack.get('gl_vendor', '?')} / {stack.get('gl_renderer', '?')} / "
          f"{stack.get('gl_version', '?')} ({family})")  # fmt: skip
    unlike = [
        f"{key.removesuffix('_version')} {goldens.stack.get(key)}"
        for key in VERSION_KEYS
        if goldens.stack.get(key) != stack.get(key)
    ]
    text = f"python {platform.python_version()}, {versions}; {gl}; GPU {gpu()}"
    if unlike:
        text += f"; the goldens were made with {', '.join(unlike)}"
    return Check("stack", True, text)


def simulator_checks(goldens_folder: str | None = None, perturbations=(), tolerance_m: float = TOLERANCE_M,
                     progress=None) -> list[Check]:  # fmt: skip
    """Replay the goldens of this stack (or the nearest stack's) and judge: the stack, physics, rendering checks.
    ``progress``: a stream to say what is under way on (it takes a while)."""
    from conflictbench.sim.stack import stack_probe

    key = golden_files.this_stack_key(stack_probe(False))
    goldens, own = golden_files.choose(key, goldens_folder)
    if progress is not None:
        print(f"doctor: replaying {len(goldens.episodes)} golden episodes of {goldens.stack_key}, with and without "
              "cameras...", file=progress, flush=True)  # fmt: skip
    blind, seeing = play_both_ways(jobs_of(goldens), goldens.image_size, perturbations)
    family = golden_files.renderer_family(seeing.stack.get("gl_vendor", ""), seeing.stack.get("gl_renderer", ""))
    against = (
        f"goldens {goldens.stack_key} (this stack's)"
        if own
        else f"goldens {goldens.stack_key}, the nearest: none were made on this stack, {key}"
    )
    if perturbations:
        against += f"; physics perturbed: {', '.join(f'{name}={value:g}' for name, value in perturbations)}"
    return [
        stack_check(seeing.stack, goldens, family),
        physics_check(compare_all(blind.replays + seeing.replays, goldens), against, tolerance_m),
        rendering_check(compare_frames(seeing.replays, goldens), family, goldens.renderer_family),
    ]
