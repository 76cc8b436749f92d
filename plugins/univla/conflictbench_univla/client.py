"""UniVLA as conflictbench sees it: UniVLA's LIBERO evaluation loop, with the model behind our REST server.

``UNIVLA_CODE=/path/to/UniVLA conflictbench model=univla model.checkpoint=DIR`` starts ``conflictbench-serve univla``
in the model environment for a UniVLA checkpoint folder (UniVLA's code read from that checkout);
``model.server=http://HOST:PORT`` plays against a running one (upstream has no server: its evaluation runs the
model in-process). The server answers each query's normalized chunk and
latent tokens; this client keeps, per episode, what upstream's loop keeps: the previous query's latent tokens (the
next prompt's history) and the action decoder's ensembling window; it un-normalizes the ensembled action with the
statistics the server's metadata carries and maps the gripper as OpenVLA's client does. One action per step.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from conflictbench import (
    HostedConfig,
    HostedPolicy,
    InfrastructureError,
    Observation,
    PerEpisode,
    UserError,
    hookimpl,
    published_results,
    sampling_seed,
)
from conflictbench.core import PolicyError
from conflictbench.hosting.openvla_family import env_gripper, policy_image, unnorm_key, unnormalize
from conflictbench.hosting.rest import JsonNumpyTransport

from .checkpoints import POLICY_TYPE, fingerprint
from .processing import UNIVLA_MAX_STEPS, TemporalEnsemble, history_text, unreadable_tokens
from .protocol import NOISE_SEED_LIMIT, act_request, read_reply
from .server import SERVED


@dataclass
class UnivlaConfig(HostedConfig):
    """Settings of ``univla`` (``model.<field>=value``; the shared ones are :class:`conflictbench.HostedConfig`'s)."""

    checkpoint: str = ""
    """A UniVLA checkpoint folder (the VLA and ``action_decoder.pt``; our server is started for it, with UniVLA's
    code from ``UNIVLA_CODE``); with ``server``, the name of what that server hosts where it does not say."""
    server: str = ""
    """``http://HOST:PORT`` of a running ``conflictbench-serve univla``."""
    unnorm_key: str = "suite"
    """The statistics to un-normalize with: ``suite`` (the episode's LIBERO suite, or its ``_no_noops`` key where
    the checkpoint has only that, as upstream's evaluation falls back), ``suite_no_noops``, or a key as it is."""
    center_crop: bool = True
    """Crop the centre 0.9 of the image's area, as UniVLA's LIBERO evaluation does."""


@dataclass
class _Episode:
    """One stream's episode: the latent tokens of its last query and its ensembling window."""

    history: str
    ensemble: TemporalEnsemble


class UnivlaPolicy(HostedPolicy):
    """UniVLA's LIBERO client: the cropped agentview image, the task text and the latent history; one action a step."""

    served = SERVED  # its check reads UniVLA's code from UNIVLA_CODE, as the started server will
    transport = JsonNumpyTransport
    url_scheme = "http"
    policy_types = {"univla": POLICY_TYPE}
    default_max_steps = UNIVLA_MAX_STEPS
    fingerprint = staticmethod(fingerprint)

    def __init__(self, *args, **kwargs):
        self._episodes = PerEpisode(lambda: _Episode("", TemporalEnsemble(self.window)))
        self._lock = threading.Lock()
        self.window = 0
        self.statistics: dict[str, dict] = {}
        super().__init__(*args, **kwargs)
        if self.checkpoint is None:
            try:
                self._read_metadata()
            except BaseException:
                self.close()
                raise

    def start(self) -> None:
        super().start()
        if not self.window:
            self._read_metadata()

    def _read_metadata(self) -> None:
        window, statistics = self.metadata.get("window"), self.metadata.get("action_statistics")
        if not window or not isinstance(statistics, dict) or not statistics:
            raise UserError(
                f"the server at {self.cfg.server} does not say its ensembling window and action statistics: "
                "UniVLA plays against conflictbench-serve univla (upstream has no server)"
            )
        self.window, self.statistics = int(window), statistics

    def _episode(self, observation: Observation) -> _Episode:
        with self._lock:  # a new episode on a stream starts with no history and an empty window
            return self._episodes(observation)

    def _key(self, observation: Observation) -> str:
        return unnorm_key(self.cfg.unnorm_key, observation.suite, self.statistics)

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None:
            raise UserError(f"{self.name} needs the agentview camera image")
        key = self._key(observation)
        if key not in self.statistics:
            raise InfrastructureError(
                f"the server has no statistics {key!r} (it has: {', '.join(sorted(self.statistics))})"
            )
        image = policy_image(observation.agentview_image, crop=self.cfg.center_crop)
        seed = sampling_seed(observation) % NOISE_SEED_LIMIT
        return act_request(image, observation.instruction, self._episode(observation).history, key, seed)

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        chunk, tokens = read_reply(reply, self.window)
        unreadable = unreadable_tokens(tokens)
        if unreadable:  # upstream's history lookup raises IndexError there, and its loop ends the episode
            raise PolicyError(
                f"the model generated latent token id {unreadable[0]}, which is no <ACT_0> .. <ACT_31>: UniVLA's "
                "loop cannot write it into the next prompt's history and ends the episode (IndexError)"
            )
        episode = self._episode(observation)
        episode.history = history_text(tokens)
        ensembled = episode.ensemble.add(chunk)
        stats = self.statistics[self._key(observation)]
        return env_gripper(unnormalize(ensembled, stats))


def load(name: str, cfg: UnivlaConfig) -> UnivlaPolicy:
    """The policy for ``model=univla``, connected to ``cfg.server``."""
    return UnivlaPolicy.load(name, cfg)


@hookimpl
def conflictbench_register_policies(register):
    register("univla", load=functools.partial(load, "univla"), config=UnivlaConfig)


#: What the model's authors published on LIBERO, with its citations (published.toml).
conflictbench_register_published_results = published_results(__package__)
