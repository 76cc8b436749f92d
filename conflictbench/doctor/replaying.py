"""Playing the golden episodes again, with cameras and without, each way in a process of its own.

Why not ``sim.replay.replay``: the doctor needs the first success state, both cameras at chosen states, a
camera-less env and a way to perturb the physics, none of which the viewer's videos need, and any change under
``conflictbench/sim`` changes the code identity of every stored episode. So this loop restates the replay's few
lines (seed, reset, initial state, warm-up, the camera gate) with the simulator's own helpers, and judges its
paths with the replay's :func:`~conflictbench.sim.replay.path_deviation`.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from conflictbench.core import UserError
from conflictbench.sim.libero_env import CAMERAS, EnvSettings

from .goldens import GoldenEpisode

#: What ``--perturb`` may change (a developer's tool: it shows what a different simulator does to the goldens).
#: ``qpos_ulp=N`` moves every joint position of the initial state N units in the last place (another CPU's
#: rounding, in effect); the others set ``model.opt.<name>`` after every reset (a reset rebuilds the model).
OPT_FIELDS = ("iterations", "tolerance", "timestep", "ls_iterations", "noslip_iterations", "impratio")
PERTURBATIONS = (*OPT_FIELDS, "qpos_ulp")


def parse_perturbations(texts: list[str]) -> tuple[tuple[str, float], ...]:
    """``["iterations=5"]`` -> ``(("iterations", 5.0),)``; a mistake is the user's."""
    out = []
    for text in texts:
        name, _, value = text.partition("=")
        if name not in PERTURBATIONS:
            raise UserError(f"--perturb {text!r}: the name is one of {', '.join(PERTURBATIONS)}, e.g. iterations=5")
        try:
            out.append((name, float(value)))
        except ValueError:
            raise UserError(f"--perturb {text!r}: the value is a number, e.g. {name}=5") from None
    return tuple(out)


@dataclass(frozen=True)
class DoctorJob:
    """A golden episode to play again (its task, initial state, seed, warm-up and frame states) and its actions."""

    episode: GoldenEpisode
    actions: np.ndarray


@dataclass
class Replayed:
    """One golden episode played again: its path (H+1 states), first success state, and frames (with cameras)."""

    name: str
    cameras: bool
    path: np.ndarray | None = None
    success_state: int | None = None
    frames: dict[tuple[str, int], np.ndarray] = field(default_factory=dict)
    error: str | None = None
    seconds: float = 0.0


@dataclass
class Group:
    """All the goldens played one way, in one process, and the stack that process saw (with cameras: the GL's)."""

    cameras: bool
    stack: dict[str, str]
    replays: list[Replayed]


def _perturb_model(env, perturbations) -> None:
    opt = env.sim.model._model.opt
    for name, value in perturbations:
        if name in OPT_FIELDS:
            setattr(opt, name, type(getattr(opt, name))(value))


def _perturb_state(env, perturbations) -> None:
    for name, value in perturbations:
        if name == "qpos_ulp":
            qpos = env.sim.data.qpos
            for _ in range(int(value)):
                qpos[:] = np.nextafter(qpos, np.inf)


def play(job: DoctorJob, settings: EnvSettings, perturbations=()) -> Replayed:
    from conflictbench.sim import libero_env
    from conflictbench.sim.worker import NOOP_ACTION
    from conflictbench.tasks.libero.base_tasks import base_task, load_init_states

    start = time.perf_counter()
    episode = job.episode
    out = Replayed(episode.name, settings.needs_images)
    env = None
    try:
        env = libero_env.make_env(base_task(episode.suite, episode.task_id).bddl_path, settings, cameras=CAMERAS)
        env.seed(episode.seed)
        env.reset()
        _perturb_model(env, perturbations)
        gate = libero_env.CameraGate(env) if settings.needs_images else None

        def render_into(state: int) -> None:  # render the cameras during the next env call only for a kept state
            if gate is not None:
                gate.set(state in episode.frame_states)

        render_into(0 if episode.warmup_steps == 0 else -1)
        obs = env.set_init_state(load_init_states(episode.suite, episode.task_id)[episode.init_state])
        _perturb_state(env, perturbations)
        for k in range(episode.warmup_steps):
            render_into(0 if k == episode.warmup_steps - 1 else -1)
            obs, _, _, _ = env.step(NOOP_ACTION)
        eef_site = env.env.robots[0].eef_site_id
        path = []
        for state in range(len(job.actions) + 1):  # state 0: after the warm-up; state i: after action i
            done = bool(env.check_success()) if state == 0 else False
            if state:
                render_into(state)
                obs, _, done, _ = env.step(np.asarray(job.actions[state - 1], dtype=np.float64))
            path.append(env.sim.data.site_xpos[eef_site].copy())
            if done and out.success_state is None:
                out.success_state = state
            if gate is not None and state in episode.frame_states:
                for camera in CAMERAS:  # upright, as people look at it (LIBERO renders upside down)
                    out.frames[camera, state] = np.ascontiguousarray(obs[f"{camera}_image"][::-1, ::-1])
        out.path = np.array(path)
    except Exception as exc:  # this replay's failure is the doctor's finding, said in its line
        out.error = f"{type(exc).__name__}: {exc}"
    finally:
        if env is not None:
            try:
                env.close()
            except Exception:  # tearing down a GL context can fail harmlessly
                pass
    out.seconds = time.perf_counter() - start
    return out


def play_group(jobs: list[DoctorJob], settings: EnvSettings, perturbations=()) -> Group:
    """In a fresh process: set it up as a simulator worker is, probe its stack, play every job one way
    (``scripts/doctor_tolerance.py`` measures with it)."""
    from conflictbench.sim import libero_env
    from conflictbench.sim.stack import stack_probe

    libero_env.configure_process(settings)
    stack = stack_probe(settings.needs_images)
    return Group(settings.needs_images, stack, [play(job, settings, perturbations) for job in jobs])


def play_half(jobs: list[DoctorJob], image_size: int, perturbations=()) -> tuple[dict[str, str], list[Replayed]]:
    """In a fresh process set up as a camera worker is: probe its stack (the GL it renders the frames with), then
    play each job without cameras and then with them, one after the other, so each scene compiles once here
    (a process keeps its last compiled scene: ``sim.compiled_models``); a camera-less env never touches the GL."""
    from conflictbench.sim import libero_env
    from conflictbench.sim.stack import stack_probe

    with_cameras = EnvSettings(True, image_size)
    libero_env.configure_process(with_cameras)
    stack = stack_probe(True)
    replays = []
    for job in jobs:
        replays.append(play(job, EnvSettings(False, image_size), perturbations))
        replays.append(play(job, with_cameras, perturbations))
    return stack, replays


def play_both_ways(jobs: list[DoctorJob], image_size: int, perturbations=()) -> tuple[Group, Group]:
    """Every job without cameras and with them, in two processes (spawned: the GL backend is chosen per process),
    each taking every other job both ways. A simulator that cannot start raises :class:`SimulatorUnavailable`."""
    from conflictbench.sim.slots import sigint_ignored

    halves = [jobs[0::2], jobs[1::2]]
    executor = ProcessPoolExecutor(max_workers=2, mp_context=mp.get_context("spawn"))
    try:
        with sigint_ignored():  # its processes are born (on a submit) ignoring Ctrl-C, as the replays': we end them
            futures = [executor.submit(play_half, half, image_size, perturbations) for half in halves if half]
        said = [future.result() for future in futures]
    except BaseException:
        for process in list(getattr(executor, "_processes", {}).values()):
            process.terminate()
        executor.shutdown(wait=False, cancel_futures=True)
        raise
    executor.shutdown()
    stack = said[0][0]
    replays = [replay for _, half in said for replay in half]
    return (
        Group(False, stack, [r for r in replays if not r.cameras]),
        Group(True, stack, [r for r in replays if r.cameras]),
    )
