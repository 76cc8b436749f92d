"""VLA-JEPA as conflictbench sees it: VLA-JEPA's LIBERO client, talking to a VLA-JEPA websocket policy server.

``conflictbench model=vla-jepa model.checkpoint=DIR`` starts our server (``conflictbench-serve vla-jepa``) for a
LeRobot checkpoint in the model environment, waits until it answers, plays, and stops it.
``model.server=ws://HOST:PORT model.checkpoint=NAME model.stats=FILE`` plays against a running server
(VLA-JEPA's ``deployment/model_server/server_policy.py --ckpt_path ...`` on a GPU machine, or ours). Replies
are normalized: the client un-normalizes them with the checkpoint's statistics, as upstream's client does:
``model.stats`` (the run's ``dataset_statistics.json``; the chunk length read from the ``config.yaml`` beside
it, or given as ``model.chunk_length``), or what our server's metadata says. Upstream's server says nothing
of the model (``model.checkpoint`` names it), and its sampling noise is its own.
"""

from __future__ import annotations

import functools
import hashlib
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
from conflictbench.hosting.openpi import OpenpiTransport

from .checkpoints import POLICY_TYPE, fingerprint
from .processing import (
    MAX_STEPS,
    ActionStatistics,
    StatisticsError,
    camera_image,
    chunk_length_from_config,
    env_actions,
)
from .protocol import NOISE_SEED_LIMIT, ReplyError, infer_request, normalized_actions
from .server import SERVED


@dataclass
class VlaJepaConfig(HostedConfig):
    """Settings of ``vla-jepa`` (``model.<field>=value``; the shared ones are :class:`conflictbench.HostedConfig`'s)."""

    # The statistics count by content (in the policy's identity), not by where the file lies.
    identity_exempt: ClassVar[tuple[str, ...]] = (*HostedConfig.identity_exempt, "stats")
    minimums: ClassVar = {**HostedConfig.minimums, "chunk_length": 0}

    checkpoint: str = ""
    """A LeRobot VLA-JEPA checkpoint folder (a server is started for it); with ``server``, the name of what
    that server hosts (upstream's server does not say)."""
    server: str = ""
    """``ws://HOST:PORT`` of a running VLA-JEPA policy server; empty: start one for ``checkpoint``."""
    stats: str = ""
    """The checkpoint run's ``dataset_statistics.json`` (the action statistics the client un-normalizes with);
    empty: the ones our server sends (upstream's sends none)."""
    unnorm_key: str = ""
    """Which dataset's statistics to use; empty: the file's only one (sent to the server as ``unnorm_key``)."""
    chunk_length: int = 0
    """Actions of each chunk executed; 0: ``future_action_window_size + 1`` from the ``config.yaml`` beside
    ``stats``."""
    max_steps: int = 0
    """Policy steps per episode; 0: VLA-JEPA's LIBERO budget (250 / 280 / 300 / 520)."""


class VlaJepaPolicy(HostedPolicy):
    """VLA-JEPA's LIBERO client: upright area-resized 224-px images, the 8-D state, the task text; whole chunks.

    The action statistics and chunk length come from ``model.stats`` where given, else from what our server
    says it hosts (its metadata; read when the policy connects, or when it starts the server).
    """

    served = SERVED
    transport = OpenpiTransport
    policy_types = {"vla-jepa": POLICY_TYPE}
    default_max_steps = MAX_STEPS
    fingerprint = staticmethod(fingerprint)

    def __init__(self, name: str, cfg: VlaJepaConfig, checkpoint: Path | None = None, python: Path | None = None):
        self.statistics: ActionStatistics | None = None
        self.chunk_length = 0
        identity = {}
        if cfg.stats:  # read before connecting: a bad file is the user's mistake, reported at once
            self.statistics, self.chunk_length, digest = read_statistics(cfg)
            identity = {"stats": digest, "chunk_length": self.chunk_length}
        super().__init__(name, cfg, checkpoint, python)
        if self.statistics is None and checkpoint is None:
            try:
                self._statistics_from_metadata()
            except BaseException:
                self.close()
                raise
        self.identity = {**self.identity, **identity}

    def start(self) -> None:
        super().start()
        if self.statistics is None:
            self._statistics_from_metadata()

    def _statistics_from_metadata(self) -> None:
        """The statistics and chunk length our server sends; UserError where the server sends none."""
        statistics, chunk_length = self.metadata.get("action_statistics"), self.metadata.get("chunk_length")
        if statistics is None or not chunk_length:
            raise UserError(
                f"the server at {self.cfg.server} does not send its action statistics (VLA-JEPA's own server "
                "does not): give model.stats=FILE, the checkpoint run's dataset_statistics.json; the server "
                "answers normalized actions, and the client un-normalizes them with those statistics"
            )
        try:
            self.statistics = ActionStatistics.from_mapping(statistics)
        except StatisticsError as exc:
            raise InfrastructureError(f"the server at {self.cfg.server} sent unusable statistics: {exc}") from None
        if self.cfg.chunk_length > int(chunk_length):
            raise UserError(
                f"model.chunk_length={self.cfg.chunk_length} is more than the {chunk_length} actions a chunk of "
                f"the server at {self.cfg.server} holds"
            )
        self.chunk_length = self.cfg.chunk_length or int(chunk_length)

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None or observation.wrist_image is None:
            raise UserError(f"{self.name} needs both camera images")
        images = [camera_image(observation.agentview_image), camera_image(observation.wrist_image)]
        return infer_request(
            images,
            observation.instruction,
            observation.state,
            request_id=f"{observation.episode_id}/{observation.step}",
            unnorm_key=self.cfg.unnorm_key or None,
            seed=sampling_seed(observation) % NOISE_SEED_LIMIT,
        )

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        try:
            chunk = normalized_actions(reply)
        except ReplyError as exc:
            raise InfrastructureError(f"{self.cfg.server} answered an error: {exc}") from None
        return env_actions(chunk, self.statistics, self.chunk_length)


def read_statistics(cfg: VlaJepaConfig) -> tuple[ActionStatistics, int, str]:
    """``model.stats``' action statistics, the chunk length and a digest of the file; UserError if unusable."""
    path = Path(cfg.stats).expanduser()
    try:
        statistics = ActionStatistics.from_file(path, cfg.unnorm_key or None)
        chunk_length = cfg.chunk_length
        if not chunk_length:
            config = path.parent / "config.yaml"
            if not config.is_file():
                raise StatisticsError(
                    f"no config.yaml beside {path} to read the chunk length from: give model.chunk_length=N "
                    "(future_action_window_size + 1 of the checkpoint)"
                )
            chunk_length = chunk_length_from_config(config)
    except StatisticsError as exc:
        raise UserError(str(exc)) from None
    digest = "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()[:24]
    return statistics, chunk_length, digest


def load(name: str, cfg: VlaJepaConfig) -> VlaJepaPolicy:
    """The policy for ``model=vla-jepa``: connected to ``cfg.server``, or ready to start a server for
    ``cfg.checkpoint``."""
    return VlaJepaPolicy.load(name, cfg)


@hookimpl
def conflictbench_register_policies(register):
    register("vla-jepa", load=functools.partial(load, "vla-jepa"), config=VlaJepaConfig)


#: What the model's authors published on LIBERO, with its citations (published.toml).
conflictbench_register_published_results = published_results(__package__)
