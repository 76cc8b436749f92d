"""The π policies as conflictbench sees them: openpi's LIBERO client, talking to an openpi server.

``conflictbench model=pi05 model.checkpoint=DIR`` starts our server (``conflictbench-pi0 serve``) in the
model environment, waits until it answers, plays, and stops it; ``model.server=ws://HOST:PORT`` talks to a
server that is already running (ours, or openpi's own ``scripts/serve_policy.py`` on a GPU machine).
"""

from __future__ import annotations

import dataclasses
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from conflictbench import (
    Observation,
    PolicyClient,
    ServedPolicy,
    ServerProcess,
    ServingConfig,
    UserError,
    free_port,
    model_environment,
    sampling_seed,
)
from conflictbench.core import DEFAULT_MAX_STEPS

from .checkpoints import POLICY_TYPES, CheckpointError, check_checkpoint
from .processing import REPLAN_STEPS, camera_image
from .protocol import ACTIONS, IMAGE, NOISE_SEED, NOISE_SEED_LIMIT, PROMPT, STATE, WRIST_IMAGE
from .transport import OpenpiTransport

#: The model environment ``scripts/setup.sh --models pi0`` builds (inside the running environment).
ENVIRONMENT = "pi0"
#: Set for every model process: bfloat16 kernels beyond AVX512 kill some CPUs' VMs (SIGILL).
MODEL_PROCESS_ENV = {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16"}


@dataclass
class PiConfig(ServingConfig):
    """Settings of ``pi0``, ``pi0-fast`` and ``pi05`` (``model.<field>=value``)."""

    identity_exempt: ClassVar[tuple[str, ...]] = (
        *ServingConfig.identity_exempt,
        "python",
        "device",
        "max_batch",
        "startup_timeout_s",
    )

    checkpoint: str = ""
    """A LeRobot π checkpoint folder (a server is started for it); with ``server``, the name of what that
    server hosts. Part of every episode's identity."""
    server: str = ""
    """``ws://HOST:PORT`` of a running openpi server; empty: start one for ``checkpoint``."""
    replan_steps: int = REPLAN_STEPS
    """Actions of each chunk executed before asking again (openpi's LIBERO client: 5)."""
    max_steps: int = 0
    """Policy steps per episode; 0: openpi's budget per LIBERO suite (220 / 280 / 300 / 520). A shorter
    budget (a smoke test) ends episodes early; it is part of every episode's identity."""
    python: str = ""
    """The model environment's interpreter for the started server (default: the one set-up made)."""
    device: str = "auto"
    """Where the started server runs the model: ``cuda``, ``cpu`` or ``auto`` (cuda when there is one)."""
    max_batch: int = 32
    """Most requests the started server answers with one forward pass."""
    startup_timeout_s: float = 900.0
    """Limit for the started server to load the checkpoint and answer."""


class PiPolicy(ServedPolicy):
    """openpi's LIBERO client: upright letterboxed images, the 8-D state, the prompt; 5 of each chunk."""

    needs_images = True

    def __init__(self, name: str, cfg: PiConfig, server: ServerProcess | None = None):
        self.name, self.replan_steps, self.server = name, cfg.replan_steps, server
        if cfg.max_steps:
            self.max_steps = {suite: cfg.max_steps for suite in DEFAULT_MAX_STEPS}
        try:
            super().__init__(PolicyClient.from_config(cfg, transport=OpenpiTransport))
            self._check_hosted(self.client.open())
        except BaseException:
            if server is not None:
                server.stop()
            raise

    def _check_hosted(self, transport: OpenpiTransport) -> None:
        hosted = transport.metadata.get("policy_type")  # our server says; openpi's may not
        if hosted is not None and hosted != POLICY_TYPES[self.name]:
            raise UserError(f"the server at {transport.url} hosts a {hosted} policy, not {self.name}")

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
        return actions[: self.replan_steps]

    def close(self) -> None:
        try:
            super().close()
        finally:
            if self.server is not None:
                self.server.stop()


def load(name: str, cfg: PiConfig) -> PiPolicy:
    """The policy for ``model=name``: connected to ``cfg.server``, or to a server started for ``cfg.checkpoint``."""
    if cfg.replan_steps < 1 or cfg.max_steps < 0:
        raise UserError(
            f"model.replan_steps must be >= 1 and model.max_steps >= 0, got {cfg.replan_steps} and {cfg.max_steps}"
        )
    if cfg.server:
        if not cfg.checkpoint:
            raise UserError(
                f"model.server={cfg.server} also needs model.checkpoint=NAME, naming what that server hosts "
                "(it is part of every episode's identity, so results of different checkpoints never mix)"
            )
        return PiPolicy(name, cfg)
    if not cfg.checkpoint:
        raise UserError(
            f"model={name} needs model.checkpoint=DIR (a LeRobot π checkpoint) or model.server=ws://HOST:PORT"
        )
    try:
        checkpoint = check_checkpoint(cfg.checkpoint, name)
    except CheckpointError as exc:
        raise UserError(str(exc)) from None
    server, url = start_server(name, checkpoint, cfg)
    return PiPolicy(name, dataclasses.replace(cfg, server=url), server)


def start_server(name: str, checkpoint: Path, cfg: PiConfig) -> tuple[ServerProcess, str]:
    """``conflictbench-pi0 serve`` for ``checkpoint`` in the model environment, answering; and its URL."""
    python = Path(cfg.python).expanduser() if cfg.python else model_environment(ENVIRONMENT) / "bin" / "python"
    if not python.exists():
        raise UserError(
            f"no model environment at {python}: build it with `scripts/setup.sh --models pi0`, "
            "or point model.python= at a Python with the plugin's server extra"
        )
    port = free_port()
    argv = [str(python), "-m", "conflictbench_pi0", "serve", "--policy", name, "--checkpoint", str(checkpoint)]
    argv += ["--host", "127.0.0.1", "--port", str(port), "--device", cfg.device, "--max-batch", str(cfg.max_batch)]
    env = {key: value for key, value in MODEL_PROCESS_ENV.items() if key not in os.environ}
    health = f"http://127.0.0.1:{port}/healthz"
    server = ServerProcess(argv, name="pi0", health_url=health, env=env, startup_timeout_s=cfg.startup_timeout_s)
    print(f"conflictbench: starting the {name} server for {checkpoint} (log: {server.log_path})", file=sys.stderr)
    server.start()
    return server, f"ws://127.0.0.1:{port}"
