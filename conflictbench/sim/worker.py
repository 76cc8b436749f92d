"""A worker process: owns one LIBERO env and plays episodes step by step for the main process.

The policy never runs here. For each episode the worker sends an :class:`Observation` whenever the
policy must decide, receives the chunk of actions to execute (raw and post-processed), and
finally sends back the recorded arrays.
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from conflictbench.core import SIMULATOR_ERROR_PREFIX, ConflictCase

NOOP_ACTION = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0])


@dataclass(frozen=True)
class EpisodeJob:
    episode_id: str
    suite: str
    task_id: int
    bddl_path: str
    init_state: int
    seed: int
    instruction: str
    """The prompt text the policy gets (also handed over in every observation)."""
    goal: tuple[tuple[str, ...], ...]
    targets: tuple[str, ...]
    warmup_steps: int
    max_steps: int
    needs_privileged: bool
    case: ConflictCase | None = None
    stream: int = 0


@dataclass
class EpisodeOutcome:
    success: bool = False
    steps: int = 0
    error: str | None = None
    eef_pos: list[np.ndarray] = field(default_factory=list)
    target_pos: list[np.ndarray] = field(default_factory=list)
    target_names: tuple[str, ...] = ()
    actions: list[np.ndarray] = field(default_factory=list)
    raw_actions: list[np.ndarray] = field(default_factory=list)
    wall_time_s: float = 0.0

    def arrays(self) -> dict[str, Any]:
        k = len(self.target_names)
        return {
            "success": self.success,
            "steps": self.steps,
            "error": self.error,
            "eef_pos": np.array(self.eef_pos, dtype=np.float64).reshape(-1, 3),
            "target_pos": np.array(self.target_pos, dtype=np.float64).reshape(-1, k, 3),
            "target_names": self.target_names,
            "actions": np.array(self.actions, dtype=np.float64).reshape(-1, 7),
            "raw_actions": np.array(self.raw_actions, dtype=np.float64).reshape(-1, 7),
            "wall_time_s": self.wall_time_s,
        }


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
            from conflictbench.tasks.libero_tasks import load_init_states

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
        from .capture import make_observation, privileged_state, target_resolver

        start = time.perf_counter()
        out = EpisodeOutcome(target_names=job.targets)
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
                conn.send(("obs", make_observation(raw, step=out.steps, instruction=job.instruction, stream=job.stream,
                                                   images=gate is not None, privileged=priv)))
                reply = conn.recv()
                if reply[0] == "abort":
                    out.error = reply[1]
                    break
                _, raw_chunk, executed_chunk = reply
                last = len(executed_chunk) - 1
                for i, (raw_action, action) in enumerate(zip(raw_chunk, executed_chunk)):
                    render_next(i == last and out.steps + 1 < job.max_steps)
                    raw, _, done, _ = env.step(action)
                    out.steps += 1
                    out.raw_actions.append(np.asarray(raw_action, dtype=np.float64))
                    out.actions.append(np.asarray(action, dtype=np.float64))
                    record()
                    if done:
                        out.success = True
                        break
                    if out.steps >= job.max_steps:
                        break
        except Exception as exc:  # the simulator failed: keep what was recorded, report, go on
            out.error = f"{SIMULATOR_ERROR_PREFIX}: {type(exc).__name__}: {exc}"
            out.success = False
            self.close()
            traceback.print_exc()
        out.wall_time_s = time.perf_counter() - start
        return out


def worker_main(conn, settings) -> None:
    """Entry point of a worker process (started with the 'spawn' method)."""
    from conflictbench.core import SimulatorUnavailable

    try:
        from . import libero_env

        libero_env.configure_process(settings)
        player = EpisodePlayer(settings)
        import libero.libero.envs  # noqa: F401  (import the simulator now, not inside the first episode)

        conn.send(("ready", libero_env.simulator_versions()))
    except SimulatorUnavailable as exc:
        conn.send(("fatal", str(exc)))
        return
    except Exception as exc:
        conn.send(("fatal", f"worker could not start the simulator: {type(exc).__name__}: {exc}"))
        return
    try:
        while True:
            msg = conn.recv()
            if msg[0] == "stop":
                break
            if msg[0] == "episode":
                outcome = player.play(msg[1], conn)
                conn.send(("done", outcome.arrays()))
    except (EOFError, KeyboardInterrupt, BrokenPipeError):
        pass
    finally:
        player.close()
