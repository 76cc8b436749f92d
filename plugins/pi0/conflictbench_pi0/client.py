"""The π policies as conflictbench sees them: openpi's LIBERO client, talking to an openpi server.

``conflictbench model=pi05 model.checkpoint=DIR`` starts our server (``conflictbench-pi0 serve``) in the
model environment, waits until it answers, plays, and stops it; ``model.server=ws://HOST:PORT`` talks to a
server that is already running (ours, or openpi's own ``scripts/serve_policy.py`` on a GPU machine).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
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
    ServerUnavailable,
    ServingConfig,
    UserError,
    free_port,
    model_environment,
    sampling_seed,
)
from conflictbench.core import DEFAULT_MAX_STEPS

from .checkpoints import DEVICE, POLICY_TYPES, CheckpointError, check_checkpoint, fingerprint
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

    # ``checkpoint`` and ``max_batch`` count through the policy's ``identity`` (the checkpoint's content,
    # the server's batch shape), not as typed: the same weights at another path are the same model.
    identity_exempt: ClassVar[tuple[str, ...]] = (
        *ServingConfig.identity_exempt,
        "checkpoint",
        "max_batch",
        "python",
        "device",
        "startup_timeout_s",
    )

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
    python: str = ""
    """The model environment's interpreter for the started server (default: the one set-up made)."""
    device: str = "auto"
    """Where the started server runs the model: ``cuda``, ``cuda:N``, ``cpu`` or ``auto`` (cuda if any)."""
    max_batch: int = 2
    """Rows of every forward pass of the started server (the waiting requests, padded with copies): set it
    to ``run.workers`` (default 2). Float rounding follows the batch shape, so it is part of every
    episode's identity; a call costs as much as ``max_batch`` requests on a CPU, about one on a GPU."""
    startup_timeout_s: float = 900.0
    """Limit for the started server to load the checkpoint and answer."""


class PiPolicy(ServedPolicy):
    """openpi's LIBERO client: upright letterboxed images, the 8-D state, the prompt; 5 of each chunk.

    With a local checkpoint the server is started by :meth:`start` (only when the run has episodes to
    play); with ``server`` the policy connects at once and reads what the server says it hosts.
    """

    needs_images = True

    def __init__(self, name: str, cfg: PiConfig, checkpoint: Path | None = None, python: Path | None = None):
        self.name, self.cfg, self.checkpoint, self.python = name, cfg, checkpoint, python
        self.replan_steps = cfg.replan_steps
        if cfg.max_steps:
            self.max_steps = {suite: cfg.max_steps for suite in DEFAULT_MAX_STEPS}
        self.server: ServerProcess | None = None
        self.client: PolicyClient | None = None
        if checkpoint is not None:
            self.identity = {"checkpoint": fingerprint(checkpoint), "max_batch": cfg.max_batch}
        else:
            metadata = self._connect(cfg)
            hosted = metadata.get("checkpoint_fingerprint") or cfg.checkpoint  # ours says; openpi's does not
            self.identity = {"checkpoint": hosted, "max_batch": int(metadata.get("max_batch", 1))}

    def start(self) -> None:
        if self.checkpoint is None or self.client is not None:
            return
        python = self.python or model_python(self.cfg)
        self.server, url = start_server(self.name, self.checkpoint, self.cfg, python)
        try:
            metadata = self._connect(dataclasses.replace(self.cfg, server=url))
        except BaseException:
            self.close()
            raise
        if metadata.get("checkpoint_fingerprint", self.identity["checkpoint"]) != self.identity["checkpoint"]:
            self.close()
            raise UserError(f"the checkpoint at {self.checkpoint} changed while its server was loading it")

    def _connect(self, cfg: PiConfig) -> dict[str, Any]:
        client = PolicyClient.from_config(cfg, transport=OpenpiTransport)
        try:
            metadata = client.open().metadata
            hosted = metadata.get("policy_type")
            if hosted is not None and hosted != POLICY_TYPES[self.name]:
                raise UserError(f"the server at {cfg.server} hosts a {hosted} policy, not {self.name}")
        except BaseException:
            client.close()
            raise
        self.client = client
        return metadata

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

    def act_batch(self, observations):
        if self.client is None:
            raise RuntimeError("start() was not called")
        try:
            return super().act_batch(observations)
        except ServerUnavailable as exc:
            server = self.server
            if server is None or server.exit_code is None:
                raise
            raise ServerUnavailable(
                exc.url,
                f"the {self.name} server started for this run exited with code {server.exit_code}; "
                f"its log: {server.log_path}",
            ) from None

    def close(self) -> None:
        try:
            if self.client is not None:
                self.client.close()
        finally:
            if self.server is not None:
                self.server.stop()


def load(name: str, cfg: PiConfig) -> PiPolicy:
    """The policy for ``model=name``: connected to ``cfg.server``, or ready to start a server for ``cfg.checkpoint``."""
    if cfg.replan_steps < 1 or cfg.max_steps < 0 or cfg.max_batch < 1:
        raise UserError(
            "model.replan_steps and model.max_batch must be >= 1 and model.max_steps >= 0, got "
            f"{cfg.replan_steps}, {cfg.max_batch} and {cfg.max_steps}"
        )
    if not DEVICE.fullmatch(cfg.device):
        raise UserError(f"model.device must be cpu, cuda, cuda:N or auto, got {cfg.device!r}")
    if cfg.server:
        if not cfg.checkpoint:
            raise UserError(
                f"model.server={cfg.server} also needs model.checkpoint=NAME, naming what that server hosts "
                "(part of every episode's identity where the server does not say, so results never mix)"
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
    python = model_python(cfg)  # a missing model environment is reported now, before the plan is played
    return PiPolicy(name, cfg, checkpoint.resolve(), python)


def model_python(cfg: PiConfig) -> Path:
    """The interpreter that runs the server: ``model.python``, or the model environment set-up made."""
    python = Path(cfg.python).expanduser() if cfg.python else model_environment(ENVIRONMENT) / "bin" / "python"
    if not python.exists():
        raise UserError(
            f"no model environment at {python}: build it with `scripts/setup.sh --models pi0`, "
            "or point model.python= at a Python with the plugin's server extra"
        )
    probe = subprocess.run([str(python), "-c", "import conflictbench_pi0.cli"], capture_output=True, text=True)
    if probe.returncode != 0:
        raise UserError(
            f"{python} cannot run the pi0 server ({(probe.stderr.strip().splitlines() or ['?'])[-1]}): "
            "build the model environment with `scripts/setup.sh --models pi0`"
        )
    return python


def start_server(name: str, checkpoint: Path, cfg: PiConfig, python: Path) -> tuple[ServerProcess, str]:
    """``conflictbench-pi0 serve`` for ``checkpoint`` in the model environment, answering; and its URL."""
    port = free_port()
    argv = [str(python), "-m", "conflictbench_pi0", "serve", "--policy", name, "--checkpoint", str(checkpoint)]
    argv += ["--host", "127.0.0.1", "--port", str(port), "--device", cfg.device, "--max-batch", str(cfg.max_batch)]
    env = {key: value for key, value in MODEL_PROCESS_ENV.items() if key not in os.environ}
    health = f"http://127.0.0.1:{port}/healthz"
    server = ServerProcess(argv, name="pi0", health_url=health, env=env, startup_timeout_s=cfg.startup_timeout_s)
    print(f"conflictbench: starting the {name} server for {checkpoint} (log: {server.log_path})", file=sys.stderr)
    server.start()
    return server, f"ws://127.0.0.1:{port}"
