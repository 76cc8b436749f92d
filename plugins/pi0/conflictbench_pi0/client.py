"""The π policies as conflictbench sees them: openpi's LIBERO client, talking to an openpi server.

``conflictbench model=pi05 model.checkpoint=DIR`` starts our server (``conflictbench-serve pi05``) in the
model environment, waits until it answers, plays, and stops it; ``model.server=ws://HOST:PORT`` talks to a
server that is already running (ours, or openpi's own ``scripts/serve_policy.py`` on a GPU machine).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from conflictbench import HostedConfig, HostedPolicy, Observation, UserError, hookimpl, published_results, sampling_seed
from conflictbench.hosting.openpi import OpenpiTransport

from .checkpoints import POLICY_TYPES, fingerprint
from .processing import REPLAN_STEPS, camera_image, executed_part
from .protocol import ACTIONS, IMAGE, NOISE_SEED, NOISE_SEED_LIMIT, PROMPT, STATE, WRIST_IMAGE
from .server import SERVED


@dataclass
class PiConfig(HostedConfig):
    """Settings of ``pi0``, ``pi0-fast`` and ``pi05`` (``model.<field>=value``; the shared ones are
    :class:`conflictbench.HostedConfig`'s: ``checkpoint``, ``server``, ``max_steps``, ``device``, ``max_batch``...)."""

    minimums: ClassVar = {**HostedConfig.minimums, "replan_steps": 1}

    checkpoint: str = ""
    """A LeRobot π checkpoint folder (a server is started for it); with ``server``, the name of what that
    server hosts (openpi's server does not say)."""
    server: str = ""
    """``ws://HOST:PORT`` of a running openpi server; empty: start one for ``checkpoint``."""
    replan_steps: int = REPLAN_STEPS
    """Actions of each chunk executed before asking again (openpi's LIBERO client: 5)."""
    max_steps: int = 0
    """Policy steps per episode; 0: openpi's budget per LIBERO suite (220 / 280 / 300 / 520). A shorter
    budget (a smoke test) ends episodes early; it is part of every episode's identity."""


class PiPolicy(HostedPolicy):
    """openpi's LIBERO client: upright letterboxed images, the 8-D state, the prompt; 5 of each chunk.

    With a local checkpoint the server is started by :meth:`start` (only when the run has episodes to
    play); with ``server`` the policy connects at once and reads what the server says it hosts.
    """

    served = SERVED
    transport = OpenpiTransport
    policy_types = POLICY_TYPES
    fingerprint = staticmethod(fingerprint)

    def __init__(self, name: str, cfg: PiConfig, checkpoint: Path | None = None, python: Path | None = None):
        self.replan_steps = cfg.replan_steps
        super().__init__(name, cfg, checkpoint, python)

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None or observation.wrist_image is None:
            raise UserError(f"{self.name} needs both camera images")
        return {
            IMAGE: camera_image(observation.agentview_image),
            WRIST_IMAGE: camera_image(observation.wrist_image),
            STATE: np.asarray(observation.state, dtype=np.float64),
            PROMPT: observation.instruction,
            NOISE_SEED: sampling_seed(observation) % NOISE_SEED_LIMIT,
        }

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        actions = np.asarray(reply[ACTIONS], dtype=np.float64)
        if actions.ndim != 2 or actions.shape[1] != 7 or len(actions) == 0:
            raise ValueError(f"the server's actions have shape {actions.shape}, expected (horizon, 7)")
        if len(actions) < self.replan_steps:  # openpi's client asserts it and ends the episode (main.py:145-147)
            raise ValueError(
                f"the server's chunk holds {len(actions)} actions, fewer than model.replan_steps={self.replan_steps} "
                "(openpi's LIBERO client executes none of such a chunk): lower model.replan_steps"
            )
        return executed_part(actions, self.replan_steps)


def load(name: str, cfg: PiConfig) -> PiPolicy:
    """The policy for ``model=name``: connected to ``cfg.server``, or ready to start a server for ``cfg.checkpoint``."""
    return PiPolicy.load(name, cfg)


@hookimpl
def conflictbench_register_policies(register):
    for name in POLICY_TYPES:
        register(name, load=functools.partial(load, name), config=PiConfig)


#: What the model's authors published on LIBERO, with its citations (published.toml).
conflictbench_register_published_results = published_results(__package__)
