"""The stack below the policy that a rollout depends on, probed where the rollouts run: one function, which every
worker reports when it starts and a run reads from a worker of its own before it plans (and what a ``doctor``
command is to print).

The simulator (LIBERO, robosuite, MuJoCo, numpy) always; for a policy that sees images also the renderer (the GL
backend and the vendor, renderer and version strings of the context it gets: Mesa's llvmpipe and an NVIDIA driver
render different pixels) and the image libraries a client's processing may use (Pillow, OpenCV, simplejpeg).
"""

from __future__ import annotations

import multiprocessing as mp
import os
from importlib import metadata

from conflictbench.core import SimulatorUnavailable

from .libero_env import EnvSettings, simulator_versions
from .slots import sigint_ignored

#: The store's columns for the simulator's versions (``libero_env.simulator_versions``).
SIMULATOR_COLUMNS = ("mujoco_version", "robosuite_version", "libero_version", "numpy_version")
IMAGE_LIBRARIES = ("pillow", "opencv-python", "opencv-python-headless", "simplejpeg")
PROBE_TIMEOUT_S = 120.0


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return ""


def renderer() -> dict[str, str]:
    """The GL backend (``MUJOCO_GL``) and what a context of it says it is; call where rendering is configured."""
    import mujoco
    from OpenGL import GL

    context = mujoco.GLContext(16, 16)
    context.make_current()
    try:
        said = {name: GL.glGetString(key) for name, key in (("gl_vendor", GL.GL_VENDOR), ("gl_renderer",
                GL.GL_RENDERER), ("gl_version", GL.GL_VERSION))}  # fmt: skip
    finally:
        context.free()
    strings = {name: value.decode(errors="replace") if value else "" for name, value in said.items()}
    return {"gl_backend": os.environ.get("MUJOCO_GL", ""), **strings}


def stack_probe(images: bool) -> dict[str, str]:
    """What this process's rollouts depend on below the policy: the simulator's versions and, with ``images``, the
    renderer and the installed image libraries."""
    stack = simulator_versions()
    if images:
        stack.update(renderer())
        stack.update({lib: version for lib in IMAGE_LIBRARIES if (version := _version(lib))})
    return stack


def extra_stack(stack: dict[str, str]) -> tuple[str, ...]:
    """The part of a stack the ``*_version`` columns do not hold, as ``key=value`` (``EpisodeRecord.sim_stack``)."""
    return tuple(f"{key}={value}" for key, value in sorted(stack.items()) if key not in SIMULATOR_COLUMNS)


def simulator_columns(stack: dict[str, str]) -> dict[str, str]:
    """The part of a stack the ``*_version`` columns hold."""
    return {key: stack.get(key, "") for key in SIMULATOR_COLUMNS}


def _probe_main(conn, settings: EnvSettings) -> None:
    try:
        from . import libero_env

        libero_env.configure_process(settings)
        conn.send(stack_probe(settings.needs_images))
    except Exception as exc:  # sent as text: the driver says it in one line
        conn.send(f"{type(exc).__name__}: {exc}")


#: What the probe said in this process, by settings: a machine's installation and GL stack do not change while a
#: process lives, and a process that plays many runs (a notebook, a test session) need not start one per run.
_probed: dict[EnvSettings, dict[str, str]] = {}


def probe_in_worker(settings: EnvSettings) -> dict[str, str]:
    """:func:`stack_probe` in a fresh process set up as a simulator worker is (the driver's own imports and GL state
    are not a worker's), once a process for each settings; born ignoring Ctrl-C as the workers are (the run stops
    it)."""
    if settings not in _probed:
        _probed[settings] = _probe_once(settings)
    return dict(_probed[settings])


def _probe_once(settings: EnvSettings) -> dict[str, str]:
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    process = ctx.Process(target=_probe_main, args=(child, settings), daemon=True, name="conflictbench-stack-probe")
    with sigint_ignored():
        process.start()
    child.close()
    try:
        if not parent.poll(PROBE_TIMEOUT_S):
            raise SimulatorUnavailable(f"the simulator's stack probe did not answer within {PROBE_TIMEOUT_S:.0f} s")
        said = parent.recv()
    except EOFError:
        raise SimulatorUnavailable(f"the simulator's stack probe died (exit code {process.exitcode})") from None
    except BaseException:  # Ctrl-C, a stop: no need to wait for it
        process.kill()
        raise
    finally:
        process.join(5)
        if process.is_alive():
            process.kill()
    if isinstance(said, str):
        raise SimulatorUnavailable(f"cannot start the simulator's stack: {said}")
    return said
