"""What the framework expects of a policy object, and the defaults for what it may declare."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar, runtime_checkable

import numpy as np

from .errors import PolicyError
from .records import ACTION_DIM, Observation

#: Max policy steps per LIBERO suite used by OpenVLA, OpenVLA-OFT and openpi's LIBERO clients.
DEFAULT_MAX_STEPS: Mapping[str, int] = {
    "libero_spatial": 220,
    "libero_object": 280,
    "libero_goal": 300,
    "libero_10": 520,
}
DEFAULT_WARMUP_STEPS = 10
DEFAULT_IMAGE_SIZE = 256


@dataclass(frozen=True)
class Declaration:
    """One thing a policy object may define besides ``reset`` and ``act``."""

    name: str
    default: str
    """As the documentation shows it (``none``: a method the policy may leave out)."""
    meaning: str


#: Everything a policy may declare, the one list of them: :class:`PolicyTraits` reads the attributes, and the
#: hook spec's docstring and README's table are checked against it (tests/test_policy_contract.py).
POLICY_DECLARATIONS: tuple[Declaration, ...] = (
    Declaration(
        "act_batch",
        "none",
        "`act_batch(observations) -> list[ndarray]`: several episodes' observations in one call; an exception in "
        "place of one result ends that episode alone",
    ),
    Declaration(
        "start",
        "none",
        "`start()`: called once before the first episode the run plays, never when everything is stored "
        "already (where to start a model server)",
    ),
    Declaration("close", "none", "`close()`: called whenever the run ends, started or not"),
    Declaration(
        "identity",
        "{}",
        "what the settings do not say about the model (a checkpoint's fingerprint); part of every episode's identity",
    ),
    Declaration(
        "concurrent_requests",
        "False",
        "True: `act_batch` may run in several threads at once, one observation each (a served policy)",
    ),
    Declaration("needs_images", "True", "render the two cameras for this policy"),
    Declaration("needs_privileged", "False", "simulator truth, the goal and the case: experts and oracles only"),
    Declaration(
        "needs_scene_state", "False", "object poses, regions and scene joints, nothing about the task (`SceneState`)"
    ),
    Declaration("image_size", "256", "the cameras' width and height in pixels"),
    Declaration("warmup_steps", "10", "no-op steps after the initial state, before the first query"),
    Declaration("max_steps", "220/280/300/520", "steps per LIBERO suite (a mapping suite -> steps)"),
    Declaration(
        "control_mode",
        "relative",
        "how the arm reads actions after the warm-up: `relative` (OSC deltas, LIBERO's own) or `absolute` (a target "
        "pose, as LeRobot's `--env.control_mode=absolute`; rows are stepped as float32)",
    ),
)

#: The arm's control modes a policy may declare (:attr:`PolicyTraits.control_mode`).
CONTROL_MODES = ("relative", "absolute")


@runtime_checkable
class Policy(Protocol):
    def reset(self, instruction: str) -> None: ...

    def act(self, observation: Observation) -> np.ndarray: ...


class PolicyTraits:
    """The optional declarations of a policy, with their defaults filled in."""

    def __init__(self, policy: Any):
        self.needs_images: bool = bool(getattr(policy, "needs_images", True))
        self.needs_privileged: bool = bool(getattr(policy, "needs_privileged", False))
        self.needs_scene_state: bool = bool(getattr(policy, "needs_scene_state", False))
        self.image_size: int = int(getattr(policy, "image_size", DEFAULT_IMAGE_SIZE))
        self.warmup_steps: int = int(getattr(policy, "warmup_steps", DEFAULT_WARMUP_STEPS))
        self.max_steps: dict[str, int] = {**DEFAULT_MAX_STEPS, **dict(getattr(policy, "max_steps", None) or {})}
        self.control_mode: str = str(getattr(policy, "control_mode", "relative"))
        if self.control_mode not in CONTROL_MODES:
            raise ValueError(f"control_mode must be one of {', '.join(CONTROL_MODES)}, not {self.control_mode!r}")
        self.identity: dict[str, Any] = dict(getattr(policy, "identity", None) or {})
        """What the settings do not say about the model (a checkpoint's fingerprint); part of the identity."""
        self.batched: bool = callable(getattr(policy, "act_batch", None))
        self.concurrent: bool = self.batched and bool(getattr(policy, "concurrent_requests", False))
        """``act_batch`` may run in several threads at once, one query each (a served policy: every
        worker's request goes out as soon as it asks, and the server batches them)."""

    def as_dict(self) -> dict[str, Any]:
        """The declarations that can change a rollout (part of every episode's identity).

        ``batched`` and ``concurrent`` are left out: they change how calls are scheduled, never an
        episode's actions (sampling is seeded per episode and step, see ``rng_for``).
        """
        # Declarations added later: at their default they leave identities as they were.
        later = {"needs_scene_state": False, "control_mode": "relative"}
        return {
            k: v
            for k, v in vars(self).items()
            if k not in ("batched", "concurrent") and not (k in later and v == later[k])
        }


T = TypeVar("T")


class PerEpisode(Generic[T]):
    """Per-episode state of a policy that serves concurrent episodes (one with ``act_batch``).

    ``state = self.episodes(observation)`` gives the value kept for ``observation.stream``, made
    afresh by ``factory()`` whenever that stream starts a new episode (its first query is step 0,
    and its ``episode_id`` differs from the last one seen there). ``reset(instruction)`` cannot
    say which stream starts, so such a policy keeps nothing per episode outside this.
    """

    def __init__(self, factory: Callable[[], T]):
        self._factory = factory
        self._by_stream: dict[int, tuple[str, T]] = {}

    def __call__(self, observation: Observation) -> T:
        held = self._by_stream.get(observation.stream)
        if held is None or observation.step == 0 or held[0] != observation.episode_id:
            held = (observation.episode_id, self._factory())
            self._by_stream[observation.stream] = held
        return held[1]


def as_action_chunk(raw: Any) -> np.ndarray:
    """Validate a policy's output and return it as a float64 chunk of shape (k, 7).

    Raises :class:`PolicyError` for anything else (wrong shape, an empty chunk, NaN or inf).
    """
    try:
        arr = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PolicyError(f"policy returned something that is not a numeric array: {exc}") from None
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != ACTION_DIM or arr.shape[0] == 0:
        raise PolicyError(
            f"policy returned shape {np.shape(raw)}, expected ({ACTION_DIM},) or (k, {ACTION_DIM}) with k >= 1"
        )
    if not np.all(np.isfinite(arr)):
        raise PolicyError("policy returned a non-finite action (NaN or inf)")
    return arr


def batch_outputs(policy: Any, observations: Sequence[Observation]) -> list[Any]:
    """Call ``act_batch`` and check it answered every observation."""
    out = list(policy.act_batch(list(observations)))
    if len(out) != len(observations):
        raise PolicyError(f"act_batch returned {len(out)} results for {len(observations)} observations")
    return out
