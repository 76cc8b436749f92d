"""Any LeRobot checkpoint, answering one LIBERO step at a time as ``lerobot-eval``'s rollout would (model env only).

Everything after the raw observation runs through LeRobot's own functions, in ``rollout``'s order
(``lerobot/scripts/lerobot_eval.py``, ``rollout``, at 0.6.1): ``preprocess_observation`` (images to float CHW,
the nested robot state to tensors), ``task`` set to the episode's instruction, the environment preprocessor
(``make_env_pre_post_processors``: ``LiberoProcessorStep`` flips both images and builds the 8-D state with LeRobot's
float32 axis-angle; X-VLA brings its own), the checkpoint's preprocessor (with ``lerobot-eval``'s two overrides:
the device and ``rename_map``), ``select_action`` under ``inference_mode``, the postprocessor, the environment
postprocessor, ``.to("cpu").numpy()``. The policy is built by LeRobot's ``make_policy`` from the checkpoint's
config and a ``LiberoEnv`` config, as ``lerobot-eval`` builds it.

Each episode has its own copy of the policy's state (:class:`EpisodeStates`): LeRobot keeps the action queue and
observation history (Diffusion, VQ-BeT) on the policy object, which ``rollout`` resets at an episode's start, and
the workers of a run play several episodes at once. The copy shares every module and weight and owns the rest.
An episode's steps must come in order: a step skipped, or one from before the last, is refused (it would pop
another action); the last step sent again (a client whose connection broke before the reply) gets the same answer.

Sampling: before every ``select_action`` the global generators torch, numpy and ``random`` draw from are seeded
with the step's seed (the request's ``conflictbench/noise_seed``, from the episode and step): a policy samples
only when it refills its queue, so each chunk's draws (flow-matching noise, Diffusion's scheduler, VQ-BeT's
sampling) depend on the episode and the step of the refill alone, never on call order or on other episodes.
``lerobot-eval`` seeds once per run instead, so its draws depend on everything played before (README).

Imports torch and LeRobot only inside :func:`load_backend` and the methods it enables.
"""

from __future__ import annotations

import collections
import contextlib
import copy
import dataclasses
import io
import logging
import random
import sys
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from conflictbench_serving.lerobot import refuse_unloaded_weights

from .checkpoints import CheckpointError, check_folder, fingerprint
from .protocol import (
    CAMERA_NAMES,
    CAMERAS,
    DEFAULT_CAMERA_NAMES,
    EPISODE,
    N_ACTION_STEPS,
    NOISE_SEED,
    PROMPT,
    RENAME_MAP,
    ROBOT_STATE,
    STEP,
    image_key,
)

logger = logging.getLogger(__name__)

#: A rename_map that renames nothing (see ``LeRobotBackend.__init__``).
NO_RENAME = {"observation.state": "observation.state"}
#: Episodes whose state is kept at once (a run plays at most its workers' count at a time; the oldest goes first).
MAX_EPISODES = 64
#: Processor pipelines kept, one per rename_map (a run names one).
MAX_RENAME_MAPS = 4


class StepOutOfOrder(ValueError):
    """A step that is not the next of its episode (the server answers it as an error; nothing is popped)."""


@dataclasses.dataclass
class _Episode:
    policy: Any
    next_step: int
    settings: tuple
    last: tuple[int, int, np.ndarray] | None = None
    """(step, seed, action) of the last step answered: a client that lost the reply sends that step again."""


def settings_of(request: dict) -> tuple:
    """The lerobot-eval settings a request carries, as a hashable key."""
    names = request.get(CAMERA_NAMES, DEFAULT_CAMERA_NAMES)
    return (
        tuple(sorted(names.items())),
        tuple(sorted(request.get(RENAME_MAP, {}).items())),
        int(request.get(N_ACTION_STEPS, 0)),
    )


class LeRobotBackend:
    """One loaded checkpoint: :meth:`infer_batch` answers each request with the action of its episode's step."""

    def __init__(self, folder: Path, policy_type: str, device: str) -> None:
        import lerobot
        import torch
        from lerobot.envs.configs import LiberoEnv
        from lerobot.envs.factory import make_env_pre_post_processors

        self._torch, self.folder, self.device, self.policy_type = torch, folder, device, policy_type
        if device.startswith("cuda"):  # what lerobot-eval's eval_main sets before it builds anything
            torch.backends.cudnn.benchmark = True
            torch.backends.cuda.matmul.allow_tf32 = True
        self._policies: dict[int, Any] = {}
        self.policy = self.policy_with(0)
        self.env_processors = make_env_pre_post_processors(LiberoEnv(), self.policy.config)
        self._processors: dict[tuple, tuple[Any, Any]] = {}
        self.processors(())  # the checkpoint's own pipelines load now: a broken one fails before the port is bound
        self.episodes: OrderedDict[str, _Episode] = OrderedDict()
        self.metadata: dict = {
            "policy_type": policy_type,
            "checkpoint": str(folder),
            "checkpoint_fingerprint": fingerprint(folder),
            "lerobot_version": str(lerobot.__version__),
            "n_action_steps": int(getattr(self.policy.config, "n_action_steps", 1) or 1),
            "input_features": sorted(self.policy.config.input_features),
            "action_dim": int(self.policy.config.output_features["action"].shape[0]),
        }

    def policy_with(self, n_action_steps: int) -> Any:
        """The policy as lerobot-eval builds it, with ``--policy.n_action_steps`` parsed into its config before
        ``make_policy`` where ``n_action_steps`` is not 0 (a model keeps the config it was built with: Diffusion
        slices its chunk by it). Built once; besides the checkpoint's own, a server plays one other value (each is a
        whole model more), and refuses a second."""
        if n_action_steps in self._policies:
            return self._policies[n_action_steps]
        other = [k for k in self._policies if k]
        if other:  # each value is a whole model more: a server plays the checkpoint's and one other, never more
            raise ValueError(
                f"this server plays n_action_steps={other[0]} beside the checkpoint's own; "
                f"start another for n_action_steps={n_action_steps}"
            )
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.envs.configs import LiberoEnv
        from lerobot.policies.factory import make_policy

        folder = self.folder
        try:
            # As lerobot-eval's EvalPipelineConfig reads --policy.path with --policy.n_action_steps (configs/eval.py).
            overrides = [f"--n_action_steps={n_action_steps}"] if n_action_steps else []
            config = PreTrainedConfig.from_pretrained(str(folder), cli_overrides=overrides)
            config.pretrained_path, config.device = folder, self.device
            printed = io.StringIO()
            with contextlib.redirect_stdout(printed):  # LeRobot prints, instead of raising, that weights did not load
                # make_policy checks the cameras against LiberoEnv's only where rename_map is empty; a run's camera
                # names and rename_map come with its requests, and the client checks them by the same rule before
                # the server starts (checkpoints.check_checkpoint). A rename of nothing to itself skips it here.
                policy = make_policy(config, env_cfg=LiberoEnv(), rename_map=NO_RENAME)
        except Exception as error:  # whatever LeRobot, torch or safetensors raise: this folder cannot be played
            what = f"n_action_steps={n_action_steps} with " if n_action_steps else ""
            raise CheckpointError(f"LeRobot cannot load {what}{folder}: {error_line(error)}") from None
        sys.stdout.write(printed.getvalue())
        refuse_unloaded_weights(printed.getvalue(), folder, self.policy_type)
        policy.eval()
        self._policies[n_action_steps] = policy
        return policy

    def processors(self, rename_map: tuple) -> tuple[Any, Any]:
        """The checkpoint's pre/post-processors with lerobot-eval's overrides (device, ``rename_map``), loaded once
        for each of the last :data:`MAX_RENAME_MAPS` rename maps requests named (a peer naming ever new ones makes
        the server load them again, never hold more)."""
        if rename_map in self._processors:
            self._processors[rename_map] = self._processors.pop(rename_map)  # the most recently used last
        else:
            from lerobot.policies.factory import make_pre_post_processors

            while len(self._processors) >= MAX_RENAME_MAPS:
                self._processors.pop(next(iter(self._processors)))
            self._processors[rename_map] = make_pre_post_processors(
                self.policy.config,
                pretrained_path=str(self.folder),
                preprocessor_overrides={
                    "device_processor": {"device": self.device},
                    "rename_observations_processor": {"rename_map": dict(rename_map)},
                },
            )
        return self._processors[rename_map]

    # -- episodes -----------------------------------------------------------------------------------------------

    def episode_policy(self, request: dict) -> Any:
        """The policy state of the request's episode: a fresh one, reset, at step 0; else the one its last step left."""
        name, step, settings = request[EPISODE], int(request[STEP]), settings_of(request)
        if step == 0:
            self.episodes.pop(name, None)
            self.episodes[name] = _Episode(self.fresh_policy(settings[2]), 0, settings)
            while len(self.episodes) > MAX_EPISODES:
                self.episodes.popitem(last=False)
        held = self.episodes.get(name)
        if held is None:
            raise StepOutOfOrder(f"episode {name!r} step {step} came with no step 0 before it (or it was dropped)")
        if held.settings != settings:
            raise StepOutOfOrder(f"episode {name!r}: step {step} came with other settings than its step 0")
        if held.next_step != step:
            raise StepOutOfOrder(f"episode {name!r}: step {step} came where step {held.next_step} was due")
        self.episodes.move_to_end(name)
        return held

    def fresh_policy(self, n_action_steps: int) -> Any:
        """A copy of the policy (built with ``n_action_steps``, 0: the checkpoint's) for one episode: the same
        modules and weights, its own queues, history or ensembler, then ``reset()``."""
        torch = self._torch
        policy = self.policy_with(n_action_steps)
        shell = copy.copy(policy)  # shares _modules, _parameters, _buffers: the weights
        internals = set(vars(torch.nn.Module()))
        for name, value in vars(policy).items():
            if name in internals or isinstance(value, torch.nn.Module | torch.Tensor) or name == "config":
                continue
            if isinstance(value, collections.deque | dict | list) or type(value).__module__.startswith("lerobot."):
                shell.__dict__[name] = copy.deepcopy(value)  # an episode's queue, history or ensembler
        shell.reset()
        return shell

    # -- one step -----------------------------------------------------------------------------------------------

    def infer_batch(self, requests: list[dict]) -> list[np.ndarray]:
        """Each request's action (1, action_dim), one request after another (each runs LeRobot's batch of one)."""
        return [self.step(request) for request in requests]

    def raw_observation(self, request: dict) -> dict:
        """What ``LiberoEnv._format_raw_obs`` returns, batched by one as the vector env stacks it."""
        names = dict(request.get(CAMERA_NAMES, DEFAULT_CAMERA_NAMES))
        # Copies: a frame's arrays are read-only views, where the vector env hands LeRobot arrays of its own.
        pixels = {names[camera]: np.array(request[image_key(camera)])[None] for camera in CAMERAS}
        robot_state: dict = {}
        for key, (path, _) in ROBOT_STATE.items():
            robot_state.setdefault(path[0], {})[path[1]] = np.array(request[key], dtype=np.float64)[None]
        return {"pixels": pixels, "robot_state": robot_state}

    def repeated(self, request: dict) -> np.ndarray | None:
        """The answer already given to this very step, where a client sends it again (its connection broke before
        the reply came): the policy's queue must not move twice for one step."""
        held = self.episodes.get(request[EPISODE])
        if held is None or held.last is None or held.settings != settings_of(request):
            return None
        step, seed, action = held.last
        return action.copy() if (step, seed) == (int(request[STEP]), int(request[NOISE_SEED])) else None

    def step(self, request: dict) -> np.ndarray:
        from lerobot.envs.utils import preprocess_observation

        torch = self._torch
        again = self.repeated(request)
        if again is not None:
            return again
        episode = self.episode_policy(request)
        preprocessor, postprocessor = self.processors(episode.settings[1])
        env_preprocessor, env_postprocessor = self.env_processors
        amp = getattr(episode.policy.config, "use_amp", False)  # lerobot-eval's eval_main wraps its rollout so
        autocast = torch.autocast(device_type=torch.device(self.device).type) if amp else contextlib.nullcontext()
        with torch.no_grad(), autocast:
            observation = preprocess_observation(self.raw_observation(request))
            observation["task"] = [request[PROMPT]]
            observation = preprocessor(env_preprocessor(observation))
            seed_everything(int(request[NOISE_SEED]))
            with torch.inference_mode():
                action = episode.policy.select_action(observation)
            action = env_postprocessor({"action": postprocessor(action)})["action"]
        answer = action.to("cpu").numpy()
        episode.last = (episode.next_step, int(request[NOISE_SEED]), answer.copy())
        episode.next_step += 1
        return answer


def seed_everything(seed: int) -> None:
    """Seed the generators a policy may draw from (torch's, on every device; numpy's and ``random``'s global ones)
    with ``seed``, right before ``select_action``."""
    import torch

    torch.manual_seed(seed % 2**64)
    np.random.seed(seed % 2**32)
    random.seed(seed)


def error_line(error: BaseException) -> str:
    lines = str(error).strip().splitlines()
    return f"{type(error).__name__}: {lines[0] if lines else ''}".rstrip(": ")


def load_backend(checkpoint: Path, device: str = "cpu") -> LeRobotBackend:
    """Load any LeRobot checkpoint folder for LIBERO; CheckpointError (one line) where it cannot be played."""
    folder = Path(checkpoint).expanduser()
    return LeRobotBackend(folder, check_folder(folder), device)
