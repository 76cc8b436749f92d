"""A third-party plugin, written against the public API only (``from conflictbench import ...``).

It registers a policy with settings, a metric, a prompt format for its policy and an action
post-processor, exactly as an external model package would. It was written against conflictbench 0.2: the block
below imports every name 0.2 offered a plugin (``conflictbench.__all__`` then) and the places model plugins
imported them from, several of which have moved since (``conflictbench.core.serving`` is now
``conflictbench.hosting.client``): were one gone, this plugin would fail to load.
"""

from dataclasses import dataclass

import numpy as np

from conflictbench import (  # noqa: F401  (0.2's public API, whole)
    BUILTIN_PLUGINS,
    P1_PREAMBLE,
    ActionContext,
    ConflictCase,
    EpisodeRecord,
    HostedConfig,
    HostedPolicy,
    HttpJsonTransport,
    InfrastructureError,
    Observation,
    Pair,
    PerEpisode,
    PolicyClient,
    PrivilegedState,
    ServedPolicy,
    ServerProcess,
    ServerUnavailable,
    ServingConfig,
    Transport,
    UserError,
    __version__,
    default_format_prompt,
    free_port,
    hookimpl,
    model_environment,
    plugins,
    rng_for,
    sampling_seed,
)
from conflictbench.core import (  # noqa: F401  (what 0.2's model plugins took from core)
    DEFAULT_MAX_STEPS,
    LIBERO_SUITES,
    MODEL_PROCESS_ENV,
    PolicyTraits,
)
from conflictbench.core import ServerProcess as _ServerProcess  # noqa: F401
from conflictbench.core import free_port as _free_port  # noqa: F401
from conflictbench.core import model_environment as _model_environment  # noqa: F401
from conflictbench.core.hosting import HostedConfig as _HostedConfig  # noqa: F401
from conflictbench.core.hosting import HostedPolicy as _HostedPolicy  # noqa: F401
from conflictbench.core.launch import ServerProcess as _LaunchedServerProcess  # noqa: F401
from conflictbench.core.sampling import sampling_seed as _sampling_seed  # noqa: F401
from conflictbench.core.serving import PolicyClient as _PolicyClient  # noqa: F401
from conflictbench.core.serving import ServedPolicy as _ServedPolicy  # noqa: F401
from conflictbench.core.serving import ServingConfig as _ServingConfig  # noqa: F401
from conflictbench.core.transport import HttpJsonTransport as _HttpJsonTransport  # noqa: F401
from conflictbench.core.transport import Transport as _Transport  # noqa: F401
from conflictbench.core.transport import one_line  # noqa: F401


@dataclass
class WaveConfig:
    amplitude: float = 0.5
    """Peak of the sinusoidal x motion."""
    period: int = 8
    """Steps per oscillation."""
    chunk: int = 1
    """Actions returned per query (executed open-loop)."""
    images: bool = False
    """Ask for camera images (as a VLA would)."""
    noise: float = 0.0
    """Standard deviation of Gaussian noise on x, drawn as a sampling VLA draws (``rng_for``)."""


class WavePolicy:
    needs_images = False
    max_steps = {"libero_spatial": 12, "libero_object": 12, "libero_goal": 12, "libero_10": 12}

    def __init__(self, cfg: WaveConfig):
        self.cfg = cfg
        self.needs_images = cfg.images
        self.instructions = []

    def reset(self, instruction: str) -> None:
        self.instructions.append(instruction)

    def act(self, observation):
        steps = observation.step + np.arange(self.cfg.chunk)
        x = self.cfg.amplitude * np.sin(2 * np.pi * steps / self.cfg.period)
        out = np.zeros((self.cfg.chunk, 7))
        out[:, 0] = x
        if self.cfg.noise:
            out[:, 0] += self.cfg.noise * rng_for(observation).standard_normal(self.cfg.chunk)
        out[:, 6] = -1.0
        return out if self.cfg.chunk > 1 else out[0]


@hookimpl
def conflictbench_register_policies(register):
    register("demo-wave", load=WavePolicy, config=WaveConfig)


def path_length(pair) -> float:
    """Ratio of the conflict rollout's end-effector path length to the reference's."""

    def length(record: EpisodeRecord) -> float:
        return float(np.linalg.norm(np.diff(record.eef_pos, axis=0), axis=1).sum())

    ref = length(pair.reference)
    return None if ref == 0 else length(pair.conflict) / ref


@hookimpl
def conflictbench_register_metrics(register):
    register("demo_path_ratio", compute=path_length, description="conflict/reference eef path length")


@hookimpl
def conflictbench_format_prompt(instruction, condition, policy):
    if policy != "demo-wave":
        return None
    return f"[{condition}] {instruction.upper()}"


@hookimpl
def conflictbench_postprocess_action(action, context):
    if context.policy != "demo-wave":
        return None
    out = action.copy()
    out[0] *= 0.5  # halve x, so raw and executed actions differ in a checkable way
    return out
