"""GR00T N1.7 as conflictbench sees it: GR00T's LIBERO client, talking to a GR00T policy server over ZeroMQ.

``conflictbench model=gr00t model.checkpoint=DIR`` starts our server (``conflictbench-serve gr00t``) for a
LeRobot checkpoint in the model environment, waits until it answers a ping, plays, and stops it.
``conflictbench model=gr00t model.server=tcp://HOST:5555 model.checkpoint=NAME`` plays against a running
server: NVIDIA's own (``gr00t/eval/run_gr00t_server.py --model-path DIR --embodiment-tag LIBERO_PANDA
--use-sim-policy-wrapper`` of the ``n1.7-release`` tag, on a GPU machine) or ours. NVIDIA's server does not say
what it hosts, so ``model.checkpoint`` names it (part of every episode's identity); it also draws its own sampling
noise, so its episodes are not bit-identical from run to run. A server of NVIDIA's main branch since ``3df8b38``
speaks another wire: the connection asks its ``get_modality_config`` and stops the run, naming the revision to serve.
"""

from __future__ import annotations

import functools
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from conflictbench import (
    HostedConfig,
    HostedPolicy,
    InfrastructureError,
    Observation,
    UserError,
    hookimpl,
    published_results,
    sampling_seed,
)
from conflictbench.core import LIBERO_SUITES
from conflictbench.core.deprecation import deprecated
from conflictbench.hosting.zeromq import ZmqTransport, answers_ping
from conflictbench_serving.checkpoints import NOISE_SEED_LIMIT

from .checkpoints import POLICY_TYPE, fingerprint
from .processing import ACTION_STEPS, MAX_EPISODE_STEPS, WARMUP_STEPS, env_actions, gr00t_observation
from .protocol import (
    MODALITY_CONFIG,
    RELEASE_COMMIT,
    RELEASE_TAG,
    endpoint_request,
    get_action_request,
    speaks_msgpack_numpy,
)
from .server import SERVED


@dataclass
class Gr00tConfig(HostedConfig):
    """Settings of ``gr00t`` (``model.<field>=value``; the shared ones are :class:`conflictbench.HostedConfig`'s)."""

    identity_exempt: ClassVar[tuple[str, ...]] = (*HostedConfig.identity_exempt, "api_token")
    minimums: ClassVar = {**HostedConfig.minimums, "action_steps": 1}

    checkpoint: str = ""
    """A LeRobot GR00T checkpoint folder (a server is started for it); with ``server``, the name of what that
    server hosts (NVIDIA's does not say)."""
    server: str = ""
    """``tcp://HOST:PORT`` of a running GR00T server (NVIDIA's ``run_gr00t_server.py``, port 5555 by default,
    or ours); empty: start one for ``checkpoint``."""
    action_steps: int = ACTION_STEPS
    """Actions of each chunk executed before asking again (GR00T's LIBERO evaluation: 8)."""
    max_steps: int = 0
    """Policy steps per episode; 0: GR00T's LIBERO budget, 720 in every suite (``--max-episode-steps 720``)."""
    api_token: str = ""
    """Deprecated (goes in 0.4.0; setting it warns, and it still works): the running server's API token. Hydra saves
    it with the run's config (``.hydra/config.yaml``, ``overrides.yaml``) and ``ps`` shows it on the command line:
    use ``model.token_file`` or ``$CONFLICTBENCH_SERVER_TOKEN``. A server the run starts gets a fresh token."""


class Gr00tPolicy(HostedPolicy):
    """GR00T's LIBERO client: upright 256-px images, the state split by name, the task text; 8 of each chunk."""

    warmup_steps = WARMUP_STEPS
    served = SERVED
    transport = ZmqTransport
    url_scheme = "tcp"
    policy_types = {"gr00t": POLICY_TYPE}
    default_max_steps = {suite: MAX_EPISODE_STEPS for suite in LIBERO_SUITES}
    fingerprint = staticmethod(fingerprint)
    sends_token = True  # its ping, metadata and get_action requests all carry self.token

    def __init__(self, name: str, cfg: Gr00tConfig, checkpoint: Path | None = None, python: Path | None = None):
        self.action_steps = cfg.action_steps
        super().__init__(name, cfg, checkpoint, python)
        if self.client is not None and not self.metadata:  # a running server, not ours: which wire does it speak?
            self._refuse_main_branch(cfg.server)

    def _refuse_main_branch(self, url: str) -> None:
        """Stop before any episode when the server is Isaac-GR00T's main since 3df8b38: it would fail every query."""
        assert self.client is not None
        try:
            modality_config = self.client.request(endpoint_request(MODALITY_CONFIG, self.token))
        except InfrastructureError:  # a server without the endpoint: its wire is not known to differ
            return
        if speaks_msgpack_numpy(modality_config):
            self.close()
            raise UserError(
                f"the GR00T server at {url} is Isaac-GR00T's main branch from 3df8b38 (2026-05-07) on: its "
                "msgpack_numpy decoder cannot read this client's arrays (np.save maps), so every get_action would "
                f"fail; serve with the {RELEASE_TAG} tag ({RELEASE_COMMIT}; usable up to but not including 3df8b38)"
            )

    @classmethod
    def configured_token(cls, cfg: Gr00tConfig) -> str | None:
        if not cfg.api_token:
            return super().configured_token(cfg)
        instead = "set CONFLICTBENCH_SERVER_TOKEN or model.token_file (Hydra saves model.api_token in the run's config)"
        deprecated("model.api_token", instead)
        print(f"conflictbench: warning: model.api_token is deprecated: {instead}", file=sys.stderr)
        return cfg.api_token

    def make_transport(self, url: str) -> ZmqTransport:
        return ZmqTransport(url, api_token=self.token)  # its ping carries the token too

    def ready_check(self, url: str):
        return lambda: answers_ping(url, self.token)  # ZeroMQ has no HTTP health endpoint: a server answers a ping

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None or observation.wrist_image is None:
            raise UserError(f"{self.name} needs both camera images")
        request = gr00t_observation(
            observation.agentview_image, observation.wrist_image, observation.state, observation.instruction
        )
        seed = sampling_seed(observation) % NOISE_SEED_LIMIT
        return get_action_request(request, seed=seed, api_token=self.token)

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        if not isinstance(reply, (list, tuple)) or len(reply) != 2 or not isinstance(reply[0], dict):
            raise ValueError(f"a get_action reply is [action, info], got {type(reply).__name__}")
        actions = env_actions(reply[0])
        if len(actions) < self.action_steps:  # upstream's MultiStepWrapper indexes past it: IndexError, none executed
            raise ValueError(
                f"the server's chunk holds {len(actions)} actions, fewer than model.action_steps={self.action_steps} "
                "(GR00T's LIBERO rollout executes none of such a chunk): lower model.action_steps"
            )
        return actions[: self.action_steps]


def load(name: str, cfg: Gr00tConfig) -> Gr00tPolicy:
    """The policy for ``model=gr00t``: connected to ``cfg.server``, or ready to start a server for
    ``cfg.checkpoint``."""
    return Gr00tPolicy.load(name, cfg)


@hookimpl
def conflictbench_register_policies(register):
    register("gr00t", load=functools.partial(load, "gr00t"), config=Gr00tConfig)


#: What the model's authors published on LIBERO, with its citations (published.toml).
conflictbench_register_published_results = published_results(__package__)
