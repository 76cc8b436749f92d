"""Setting up the simulator: a missing rendering stack is a clear message, not a traceback."""

from __future__ import annotations

import ctypes.util

import pytest

from conflictbench.core import SimulatorUnavailable
from conflictbench.sim import libero_env


def test_policies_without_images_never_need_gl():
    assert libero_env.choose_gl_backend(needs_images=False) == "disabled"


def test_missing_egl_names_the_packages_to_install(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "egl")
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None)  # the system's library lookup
    with pytest.raises(SimulatorUnavailable, match="apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri"):
        libero_env.choose_gl_backend(needs_images=True)


def test_egl_is_found_on_this_machine():
    assert libero_env.choose_gl_backend(needs_images=True) in ("egl", "osmesa", "glx")


@pytest.mark.sim
def test_a_simulator_that_cannot_start_is_exit_code_3_with_the_reason(cli, monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "bogus")
    out = cli("model=demo-wave", "model.images=true", "suite=physical", "level=L1", "run.libero_suites=[libero_goal]")
    assert out.returncode == 3, out.stderr[-2000:]
    assert "invalid value for environment variable MUJOCO_GL: bogus" in out.stderr
    assert "Traceback" not in out.stderr
