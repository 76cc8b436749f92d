"""A worker process: owns one LIBERO env and plays episodes step by step for the main process.

The policy never runs here. For each episode the worker sends a :class:`Query` (an observation)
whenever the policy must decide, receives the chunk of actions to execute (raw and post-processed),
and finally sends back the recorded arrays (see :mod:`.messages`).
"""

from __future__ import annotations

import contextlib
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from conflictbench.core import ACTION_DIM, SIMULATOR_ERROR_PREFIX

from .messages import Abort, Actions, Done, EpisodeJob, EpisodeOutcome, Fatal, Play, Query, Ready, Stop

NOOP_ACTION = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0])


@dataclass
class _Recording:
    """An episode's outcome while it is being played."""

    targets: int
    success: bool = False
    steps: int = 0
    error: str | None = None
    error_kind: str | None = None
    sim_warnings: tuple[str, ...] = ()
    stepping: np.ndarray | None = None
    """The policy's action the env is executing (a failure during it may be the policy's doing)."""
    eef_pos: list[np.ndarray] = field(default_factory=list)
    target_pos: list[np.ndarray] = field(default_factory=list)
    actions: list[np.ndarray] = field(default_factory=list)
    raw_actions: list[np.ndarray] = field(default_factory=list)
    waiting_s: float = 0.0
    """Time spent waiting for the policy's answers (subtracted from the simulation time)."""

    def outcome(self, elapsed_s: float) -> EpisodeOutcome:
        return EpisodeOutcome(
            success=self.success,
            steps=self.steps,
            error=self.error,
            error_kind=self.error_kind,
            sim_warnings=self.sim_warnings,
            eef_pos=np.array(self.eef_pos, dtype=np.float64).reshape(-1, 3),
            target_pos=np.array(self.target_pos, dtype=np.float64).reshape(-1, self.targets, 3),
            actions=np.array(self.actions, dtype=np.float64).reshape(-1, ACTION_DIM),
            raw_actions=np.array(self.raw_actions, dtype=np.float64).reshape(-1, ACTION_DIM),
            sim_time_s=elapsed_s - self.waiting_s,
        )


class EpisodePlayer:
    """Runs episodes on a cached env (rebuilt only when the base task changes)."""

    def __init__(self, settings):
        from . import libero_env

        self.settings = settings
        self._libero_env = libero_env
        self._env = None
        self._env_key: tuple[str, int] | None = None
        self._init_states: Any = None

    def _env_for(self, job: EpisodeJob):
        key = (job.suite, job.task_id)
        if self._env_key != key:
            self.close()
            from conflictbench.tasks.libero.base_tasks import load_init_states

            self._env = self._libero_env.make_env(job.bddl_path, self.settings)
            self._init_states = load_init_states(job.suite, job.task_id)
            self._env_key = key
        return self._env

    def close(self) -> None:
        if self._env is not None:
            try:
                self._env.close()
            except Exception:  # teardown of a GL context can fail harmlessly at exit
                pass
        self._env, self._env_key = None, None

    def play(self, job: EpisodeJob, conn) -> EpisodeOutcome:
        """Play one episode; ``conn`` carries observations out and action chunks in."""
        from .capture import controller_eef_mat, make_observation, privileged_state, scene_state, target_resolver

        start = time.perf_counter()
        out = _Recording(targets=len(job.targets))
        try:
            env = self._env_for(job)
            env.seed(job.seed)
            env.reset()
            gate = self._libero_env.CameraGate(env) if self.settings.needs_images else None

            def render_next(needed: bool) -> None:
                """Render cameras during the next env call only if the policy will see its observation."""
                if gate is not None:
                    gate.set(needed)

            render_next(job.warmup_steps == 0)
            raw = env.set_init_state(self._init_states[job.init_state])
            for k in range(job.warmup_steps):
                render_next(k == job.warmup_steps - 1)
                raw, _, _, _ = env.step(NOOP_ACTION)
            set_control_mode(env, job.control_mode)
            targets = [target_resolver(env, name) for name in job.targets]
            eef_site = env.env.robots[0].eef_site_id

            def record() -> None:
                # The end-of-step state, read from the simulator like the targets (robosuite's
                # observation values are sampled a sub-step earlier).
                out.eef_pos.append(env.sim.data.site_xpos[eef_site].copy())
                out.target_pos.append(np.array([read() for read in targets], dtype=np.float64).reshape(-1, 3))

            record()
            out.success = bool(env.check_success())
            while not out.success and out.steps < job.max_steps:
                priv = privileged_state(env, job.goal, job.case) if job.needs_privileged else None
                scene = scene_state(env) if job.needs_scene_state else None
                conn.send(
                    Query(
                        make_observation(
                            raw,
                            step=out.steps,
                            instruction=job.instruction,
                            stream=job.stream,
                            episode_id=job.episode_id,
                            sampling_key=job.sampling_key,
                            suite=job.suite,
                            images=gate is not None,
                            privileged=priv,
                            scene=scene,
                            eef_mat=controller_eef_mat(env),
                        )
                    )
                )
                asked = time.perf_counter()
                reply = conn.recv()
                out.waiting_s += time.perf_counter() - asked
                if isinstance(reply, Abort):
                    out.error, out.error_kind = reply.reason, reply.kind
                    break
                if not isinstance(reply, Actions):  # Stop: the run ends (e.g. its policy server died)
                    raise StopRequested
                last = len(reply.executed) - 1
                for i, (raw_action, action) in enumerate(zip(reply.raw, reply.executed)):
                    render_next(i == last and out.steps + 1 < job.max_steps)
                    out.stepping = action
                    raw, _, done, _ = env.step(as_stepped(action, job.control_mode))
                    out.stepping = None
                    out.steps += 1
                    out.raw_actions.append(np.asarray(raw_action, dtype=np.float64))
                    out.actions.append(np.asarray(action, dtype=np.float64))
                    record()
                    if done:
                        out.success = True
                        break
                    if out.steps >= job.max_steps:
                        break
            out.sim_warnings = simulator_warnings(env)
        except StopRequested:
            raise
        except Exception as exc:  # the simulator failed: keep what was recorded, report, go on
            traceback.print_exc()
            failure = f"{type(exc).__name__}: {exc}"
            with contextlib.suppress(Exception):
                out.sim_warnings = simulator_warnings(self._env)
            self.close()
            # The policy's doing if its actions bring a fresh simulator to the same failure: its behaviour, scored.
            policys = out.stepping is not None and self.fails_again(job, [*out.actions, out.stepping], failure)
            out.error = f"{SIMULATOR_ERROR_PREFIX}: {failure}" + (REPRODUCED if policys else "")
            out.error_kind = "policy" if policys else "simulator"
            out.success = False
        return out.outcome(time.perf_counter() - start)

    def fails_again(self, job: EpisodeJob, actions: list[np.ndarray], failure: str) -> bool:
        """Whether a fresh env fails with ``failure`` when ``actions`` are replayed from the episode's start
        (seed, initial state, warm-up; no rendering, which changes no physics)."""
        try:
            env = self._env_for(job)
            env.seed(job.seed)
            env.reset()
            if self.settings.needs_images:
                self._libero_env.CameraGate(env).set(False)
            env.set_init_state(self._init_states[job.init_state])
            for _ in range(job.warmup_steps):
                env.step(NOOP_ACTION)
            set_control_mode(env, job.control_mode)
            for action in actions:
                env.step(as_stepped(action, job.control_mode))
        except Exception as exc:
            self.close()
            return f"{type(exc).__name__}: {exc}" == failure
        return False


def set_control_mode(env, mode: str) -> None:
    """How every arm reads actions from now on: OSC deltas (``"relative"``, robosuite's configured default, which a
    reset restores) or a target pose (``"absolute"``), set on the controllers after the warm-up's delta no-ops, as
    LeRobot's LIBERO env does (``libero.py``, ``reset``: ``controller.use_delta``). Relative is what every reset
    leaves (a hard reset loads the controller's configuration anew): nothing to set."""
    if mode == "relative":
        return
    for robot in env.env.robots:
        robot.controller.use_delta = False


def as_stepped(action: np.ndarray, mode: str) -> np.ndarray:
    """The row handed to ``env.step``. Absolute control keeps the row's float32: robosuite's axis-angle to quaternion
    conversion computes in the input's dtype, and LeRobot steps its policies' float32 rows (a float32 value and its
    float64 copy give other goal rotations). Relative control scales in float64 either way."""
    return np.asarray(action, dtype=np.float32) if mode == "absolute" else action


#: Added to a simulator failure's error when the policy's actions reproduce it.
REPRODUCED = " (it happens again when the policy's actions are replayed in a fresh simulator: the policy's doing)"


def simulator_warnings(env) -> tuple[str, ...]:
    """MuJoCo's warnings in this episode's simulator, e.g. ``mjWARN_BADQACC x2`` (an unstable simulation
    that MuJoCo reset): counted since the env's last reset, which builds a new simulator."""
    import mujoco

    if env is None:
        return ()
    warnings = env.sim.data.warning
    return tuple(
        f"{mujoco.mjtWarning(i).name} x{warnings[i].number}" for i in range(len(warnings)) if warnings[i].number
    )


class StopRequested(Exception):
    """The main process sent Stop while an episode waited for actions: leave now, store nothing."""


def worker_main(conn, settings) -> None:
    """Entry point of a worker process (started with the 'spawn' method)."""
    from conflictbench.core import SimulatorUnavailable

    try:
        from . import libero_env
        from .stack import stack_probe

        libero_env.configure_process(settings)
        player = EpisodePlayer(settings)
        import libero.libero.envs  # noqa: F401  (import the simulator now, not inside the first episode)

        conn.send(Ready(stack_probe(settings.needs_images)))
    except SimulatorUnavailable as exc:
        conn.send(Fatal(str(exc)))
        return
    except Exception as exc:
        conn.send(Fatal(f"worker could not start the simulator: {type(exc).__name__}: {exc}"))
        return
    try:
        while True:
            match conn.recv():
                case Stop():
                    break
                case Play(job=job):
                    conn.send(Done(player.play(job, conn)))
                case other:
                    raise TypeError(f"a worker expects Play or Stop, got {type(other).__name__}")
    except (StopRequested, EOFError, KeyboardInterrupt, BrokenPipeError):
        pass
    finally:
        player.close()
