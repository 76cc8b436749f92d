"""A scene compiled once is the scene compiled every time: same model bytes, same physics, any process."""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytestmark = pytest.mark.sim

mujoco = pytest.importorskip("mujoco")

from conflictbench.sim import compiled_models  # noqa: E402

SMALL_SCENE = """<mujoco><worldbody><body pos="0 0 1"><freejoint/><geom size="{size}"/></body></worldbody></mujoco>"""


def model_bytes(model) -> bytes:
    buffer = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buffer)
    return buffer.tobytes()


@pytest.fixture
def fresh_process(monkeypatch):
    """No model kept from an earlier test, and no cache directory unless the test sets one."""
    monkeypatch.setattr(compiled_models, "_last", None)
    monkeypatch.delenv(compiled_models.CACHE_DIR_VARIABLE, raising=False)


@pytest.fixture(scope="module")
def libero_scene() -> str:
    """The XML robosuite compiles for a LIBERO base task (what every env build and reset compiles)."""
    from conflictbench.sim.libero_env import EnvSettings, configure_process, make_env
    from conflictbench.tasks.libero.base_tasks import base_task

    configure_process(EnvSettings(needs_images=False))
    env = make_env(base_task("libero_object", 1).bddl_path, EnvSettings(needs_images=False))
    try:
        return env.env.model.get_xml()
    finally:
        env.close()


def test_a_kept_a_stored_and_a_fresh_compile_of_a_libero_scene_are_the_same_bytes(
    libero_scene, fresh_process, monkeypatch, tmp_path
):
    fresh = model_bytes(mujoco.MjModel.from_xml_string(libero_scene))
    monkeypatch.setenv(compiled_models.CACHE_DIR_VARIABLE, str(tmp_path))
    compiled = compiled_models.compiled_model(libero_scene)  # compiled, and written as MJB
    kept = compiled_models.compiled_model(libero_scene)  # a copy of the one kept in this process
    monkeypatch.setattr(compiled_models, "_last", None)
    loaded = compiled_models.compiled_model(libero_scene)  # what a new process gets: the MJB file
    assert len(list(tmp_path.glob("*.mjb"))) == 1
    assert fresh == model_bytes(compiled) == model_bytes(kept) == model_bytes(loaded)


def test_a_loaded_libero_scene_steps_bit_identically_to_a_compiled_one(
    libero_scene, fresh_process, monkeypatch, tmp_path
):
    monkeypatch.setenv(compiled_models.CACHE_DIR_VARIABLE, str(tmp_path))
    compiled_models.compiled_model(libero_scene)
    monkeypatch.setattr(compiled_models, "_last", None)
    loaded = compiled_models.compiled_model(libero_scene)
    compiled = mujoco.MjModel.from_xml_string(libero_scene)
    rng = np.random.default_rng(0)
    controls = rng.uniform(-1, 1, (300, compiled.nu))
    paths = []
    for model in (compiled, loaded):
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        path = []
        for control in controls:
            data.ctrl[:] = control
            mujoco.mj_step(model, data)
            path.append(np.concatenate([data.qpos, data.qvel, data.qacc_warmstart]))
        paths.append(np.array(path))
    assert np.abs(paths[0][-1] - paths[0][0]).max() > 1e-3  # the scene moved
    np.testing.assert_array_equal(paths[0], paths[1])


def test_each_process_gets_its_own_copy_and_one_scene_is_kept(fresh_process):
    first = compiled_models.compiled_model(SMALL_SCENE.format(size=0.1))
    again = compiled_models.compiled_model(SMALL_SCENE.format(size=0.1))
    assert first is not again
    again.geom_size[0, 0] = 0.5  # what a caller does to its model stays its own
    assert compiled_models.compiled_model(SMALL_SCENE.format(size=0.1)).geom_size[0, 0] == pytest.approx(0.1)
    other = compiled_models.compiled_model(SMALL_SCENE.format(size=0.2))
    assert other.geom_size[0, 0] == pytest.approx(0.2)
    assert compiled_models._last[0] == compiled_models.scene_key(SMALL_SCENE.format(size=0.2))


def test_a_named_file_that_changes_is_another_scene(fresh_process, tmp_path):
    mesh = tmp_path / "part.stl"
    scene = f'<mujoco><asset><mesh file="{mesh}"/></asset></mujoco>'
    mesh.write_bytes(b"one")
    before = compiled_models.scene_key(scene)
    mesh.write_bytes(b"other")
    assert compiled_models.scene_key(scene) != before
    assert compiled_models.scene_key(SMALL_SCENE.format(size=0.1)) != compiled_models.scene_key(
        SMALL_SCENE.format(size=0.2)
    )


def test_an_unreadable_stored_model_is_compiled_again_and_replaced(fresh_process, monkeypatch, tmp_path, caplog):
    monkeypatch.chdir(tmp_path)  # MuJoCo logs the bad file to MUJOCO_LOG.TXT in the working directory
    scene = SMALL_SCENE.format(size=0.1)
    monkeypatch.setenv(compiled_models.CACHE_DIR_VARIABLE, str(tmp_path))
    stored = tmp_path / f"{compiled_models.scene_key(scene)}.mjb"
    stored.write_bytes(b"not a model")
    with caplog.at_level(logging.WARNING, logger=compiled_models.__name__):
        model = compiled_models.compiled_model(scene)
    assert "unreadable" in caplog.text
    assert model_bytes(model) == model_bytes(mujoco.MjModel.from_xml_string(scene))
    assert stored.read_bytes() == model_bytes(model)
    assert not list(tmp_path.glob("*.part"))


def test_a_cache_directory_that_cannot_be_written_only_costs_the_compile(fresh_process, monkeypatch, tmp_path, caplog):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv(compiled_models.CACHE_DIR_VARIABLE, str(blocker / "models"))
    with caplog.at_level(logging.WARNING, logger=compiled_models.__name__):
        model = compiled_models.compiled_model(SMALL_SCENE.format(size=0.1))
    assert model.ngeom == 1
    assert "cannot keep the compiled model" in caplog.text
