"""A served policy that hosts its own model: ``model.checkpoint=DIR`` starts a server, ``model.server=URL`` uses one.

Every model plugin whose model runs in a model environment (see the README's "Model plugins") shares this
lifecycle; the plugin supplies its protocol and processing (a :class:`~.client.ServedPolicy`'s ``encode``
and ``decode``) and a few declarations:

- ``served``: the plugin's ``ServedModel`` (``conflictbench_serving.command``), declared once for both halves:
  the model environment ``scripts/setup.sh --models NAME`` builds (its Python runs the server), the fast
  check, without the model stack, that a folder holds the policy's checkpoint (its message a :class:`UserError`
  here), and what ``conflictbench-serve POLICY`` hosts (``python -m conflictbench_serving POLICY --checkpoint DIR
  --host 127.0.0.1 --port 0 --device D --max-batch B --ready-fd N``, found through the plugin's
  ``conflictbench_serving`` entry point);
- ``transport`` (the protocol's :class:`~.transport.Transport`) and ``url_scheme`` (``ws``, ``tcp``, ...);
- ``fingerprint(folder)``: a digest of the checkpoint's content;
- ``HostedConfig.minimums``: the least value of each numeric setting (a plugin's config adds its own).

A plugin written before ``served`` existed declares ``environment``, ``server_module`` (whose ``serve --policy``
command hosts a checkpoint) and ``inspect_checkpoint`` instead: that way works until 0.4.0, and declaring
``server_module`` warns (``DeprecationWarning``) that ``served`` replaces it.

What it owns, the same for every model:

- **Lazy start.** Loading a checkpoint takes seconds to minutes, so :meth:`HostedPolicy.start` starts the
  server only when the run has episodes to play (the runner calls it); ``close()`` stops it.
- **Identity by content.** With a checkpoint, ``identity`` is its fingerprint, the server's ``max_batch`` (float
  rounding follows the batch shape) and the model stack (``conflictbench_serving.stack``: the device kind, ``auto``
  decided now by the model environment's torch, and every distribution's version there, read from their files by
  the environment's probe before the run plans; the started server must then report the same); against a running
  server, what its metadata says (``checkpoint_fingerprint``, ``max_batch``,
  ``model_stack``), else the name given in ``model.checkpoint`` and "unreported", said once.
- **The right model.** A server naming another ``policy_type``, or a checkpoint changed while it loaded, is refused.
- **The server it started, and no other.** A started server (``served``) binds any free port and says which over
  its own pipe (``ServerProcess(reports_address=True)``), so no process that took a port first can answer for it;
  it must say both what it loaded (``checkpoint_fingerprint``) and on what (``model_stack``), so an impostor cannot
  pass by leaving them out; and once it has exited, nothing at its port is talked to.
- **A token.** Each started server gets a fresh one (``CONFLICTBENCH_SERVER_TOKEN`` in its environment, never on its
  command line) that every request carries, so other users of the machine cannot use it; a running server's
  (``model.server``) is read from ``CONFLICTBENCH_SERVER_TOKEN`` or ``model.token_file``, never stored in the run's
  config, results or logs.
- **Clear failures.** A missing model environment is reported when the policy is loaded (before the
  plan is played); a started server that dies turns the next request's error into one naming its exit
  code and log.
"""

from __future__ import annotations

import dataclasses
import os
import secrets
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from ..core.deprecation import deprecated
from ..core.errors import ServerUnavailable, UserError
from ..core.policy import DEFAULT_MAX_STEPS
from .client import PolicyClient, ServedPolicy, ServingConfig
from .environments import MODEL_PROCESS_ENV, UNREPORTED, probe_environment, probed_stack, stack_difference
from .launch import ServerProcess, free_port, model_environment
from .transport import Transport
from .trust import TOKEN_VARIABLE, StartedServerConnection, configured_token, token_argument


@dataclass
class HostedConfig(ServingConfig):
    """Settings every hosted model shares (``model.<field>=value``); a plugin's config inherits them."""

    # ``checkpoint`` and ``max_batch`` count through the policy's ``identity`` (the checkpoint's content,
    # the server's batch shape), not as typed: the same weights at another path are the same model.
    identity_exempt: ClassVar[tuple[str, ...]] = (
        *ServingConfig.identity_exempt,
        "checkpoint",
        "max_batch",
        "python",
        "device",
        "startup_timeout_s",
        "token_file",
    )
    #: The least value of each numeric setting; a plugin's config adds its own (``{**HostedConfig.minimums, ...}``).
    minimums: ClassVar[Mapping[str, int]] = {"max_batch": 1, "max_steps": 0}

    checkpoint: str = ""
    """A local checkpoint folder (a server is started for it); with ``server``, the name of what that server
    hosts where the server does not say."""
    server: str = ""
    """The URL of a running server; empty: start one for ``checkpoint``."""
    max_steps: int = 0
    """Policy steps per episode; 0: the model's own budget per LIBERO suite. A shorter budget (a smoke test)
    ends episodes early; it is part of every episode's identity."""
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
    token_file: str = ""
    """With ``server``: a file holding that server's token (default: ``$CONFLICTBENCH_SERVER_TOKEN``, else none). A
    server the run starts gets a fresh token of its own."""


def _valid_device(device: str) -> bool:
    head, _, index = device.partition(":")
    return device in ("auto", "cpu", "cuda") or (head == "cuda" and index.isdigit())


class HostedPolicy(ServedPolicy):
    """A :class:`ServedPolicy` that starts, checks and stops its own server. Build it with :meth:`load`."""

    served: ClassVar[Any] = None
    """The plugin's ``conflictbench_serving.command.ServedModel``: environment, checkpoint check, what hosts it."""
    environment: ClassVar[str] = ""
    """Without ``served``: the model environment's name (``scripts/setup.sh --models NAME``, ``.venv/models/NAME``)."""
    server_module: ClassVar[str] = ""
    """Deprecated (goes in 0.4.0; declaring it warns): without ``served``, ``python -m server_module serve --policy P
    ...`` hosts a checkpoint in that environment."""
    transport: ClassVar[Callable[[str], Transport]]
    url_scheme: ClassVar[str] = "ws"
    policy_types: ClassVar[Mapping[str, str]] = {}
    """Our policy names and the ``policy_type`` a server of each says it hosts (none: not checked)."""
    default_max_steps: ClassVar[Mapping[str, int]] = DEFAULT_MAX_STEPS
    """The model's own budget per LIBERO suite (``model.max_steps=0``)."""
    checkpoint_errors: ClassVar[tuple[type[Exception], ...]] = ()
    """What the plugin's checkpoint checks raise for a folder that cannot be served (its message one line):
    a user mistake, reported as :class:`UserError`."""
    sends_token: ClassVar[bool | None] = None
    """Whether every request of this client carries ``self.token``; None: where the transport takes a ``token``
    argument and ``make_transport`` is not overridden (ZeroMQ's ``api_token`` is in each request: say True where
    ``encode`` puts it there). A server started for a client that does not
    is given no token (its pipe still proves it is the one started)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "server_module" in vars(cls):  # warned where the plugin declares it (the class statement)
            deprecated(
                f"{cls.__module__}.{cls.__qualname__}.server_module (HostedPolicy's)",
                "declare served = ServedModel.of(...) instead (conflictbench_serving.command), which "
                "conflictbench-serve POLICY hosts",
            )

    def __init__(self, name: str, cfg: HostedConfig, checkpoint: Path | None = None, python: Path | None = None):
        self.name, self.cfg, self.checkpoint, self.python = name, cfg, checkpoint, python
        self.token: str | None = None
        """What every request carries: a started server's fresh token, or the running server's (``model.server``)."""
        self.max_steps = {suite: cfg.max_steps or steps for suite, steps in self.default_max_steps.items()}
        self.server: ServerProcess | None = None
        self.client: PolicyClient | None = None
        self.metadata: dict[str, Any] = {}
        self.device = cfg.device
        """Where the started server runs the model: ``model.device`` with ``auto`` decided before the run plans."""
        if checkpoint is not None:
            fingerprint, stack = self.fingerprint(checkpoint), self._environment_stack(python)
            self.identity = {"checkpoint": fingerprint, "max_batch": cfg.max_batch, "model_stack": stack}
        else:
            self.token = self.configured_token(cfg)
            self.metadata = self._connect(cfg)
            hosted = self.metadata.get("checkpoint_fingerprint") or cfg.checkpoint
            stack = self.metadata.get("model_stack") or UNREPORTED
            if stack == UNREPORTED:
                print(
                    f"conflictbench: the server at {cfg.server} does not say what model stack it runs (a server of "
                    "conflictbench-serve does): its episodes count it as unreported",
                    file=sys.stderr,
                )
            self.identity = {
                "checkpoint": hosted,
                "max_batch": int(self.metadata.get("max_batch", 1)),
                "model_stack": stack,
            }

    # What a plugin supplies ----------------------------------------------------------------------------

    @classmethod
    def inspect_checkpoint(cls, name: str, folder: Path) -> Path:
        """``folder``, checked (without the model stack) to hold a checkpoint of policy ``name``; raise
        :class:`UserError` (or one of ``checkpoint_errors``) saying what is wrong otherwise. By default the
        check ``served`` declares, naming a policy as a run does (``model=NAME``)."""
        if cls.served is None:
            raise NotImplementedError
        from conflictbench_serving.checkpoints import CheckpointError  # a plugin declaring `served` has it

        try:
            cls.served.check(folder, name, "model=")
        except CheckpointError as exc:
            raise UserError(str(exc)) from None
        return folder

    @classmethod
    def fingerprint(cls, folder: Path) -> str:
        """A digest of what decides the model's actions in ``folder`` (weights, config, statistics)."""
        raise NotImplementedError

    def make_transport(self, url: str) -> Transport:
        """One connection's transport, carrying ``self.token`` where there is one (override to pass settings)."""
        argument = token_argument(type(self).transport)
        if self.token is None or argument is None:
            return type(self).transport(url)
        return type(self).transport(url, **{argument: self.token})

    def ready_check(self, url: str) -> Callable[[], bool] | None:
        """How to tell that a server at ``url`` answers; None: its ``/healthz`` over HTTP. A server of ``served``
        says so itself once it listens (its ready pipe), and the first connection, with the token, proves it; this
        check serves a plugin's own ``server_module``."""
        return None

    @classmethod
    def configured_token(cls, cfg: HostedConfig) -> str | None:
        """The token of a running server (``model.server``): ``model.token_file``'s, else
        ``$CONFLICTBENCH_SERVER_TOKEN``, else none."""
        return configured_token(cfg.token_file)

    @classmethod
    def _sends_token(cls) -> bool:
        if cls.sends_token is not None:
            return cls.sends_token
        # ZeroMQ's api_token is a field of each request the plugin builds (its encode): that plugin says so itself.
        return cls.make_transport is HostedPolicy.make_transport and token_argument(cls.transport) == "token"

    # The shared lifecycle --------------------------------------------------------------------------------

    @classmethod
    def load(cls, name: str, cfg: HostedConfig) -> HostedPolicy:
        """The policy for ``model=name``: connected to ``cfg.server``, or ready to start a server for
        ``cfg.checkpoint``. User mistakes raise :class:`UserError`."""
        for field, least in cfg.minimums.items():
            if getattr(cfg, field) < least:
                raise UserError(f"model.{field} must be >= {least}, got {getattr(cfg, field)}")
        if not _valid_device(cfg.device):
            raise UserError(f"model.device must be cpu, cuda, cuda:N or auto, got {cfg.device!r}")
        if cfg.server:
            if not cfg.checkpoint:
                raise UserError(
                    f"model.server={cfg.server} also needs model.checkpoint=NAME, naming what that server hosts "
                    "(part of every episode's identity where the server does not say, so results never mix)"
                )
            return cls(name, cfg)
        if not cfg.checkpoint:
            raise UserError(
                f"model={name} needs model.checkpoint=DIR (a local checkpoint folder) "
                f"or model.server={cls.url_scheme}://HOST:PORT (a running server)"
            )
        try:
            checkpoint = cls.inspect_checkpoint(name, Path(cfg.checkpoint).expanduser()).resolve()
        except cls.checkpoint_errors as exc:
            raise UserError(str(exc)) from None
        python = cls.model_python(cfg, name)  # a missing model environment is reported now, before the plan is played
        return cls(name, cfg, checkpoint, python)

    @classmethod
    def model_environment_name(cls) -> str:
        """The model environment's name (``scripts/setup.sh --models NAME``)."""
        return cls.served.environment if cls.served is not None else cls.environment

    def server_command(self) -> list[str]:
        """What hosts this policy's checkpoint, after the interpreter: ``conflictbench-serve POLICY``'s module, or
        a plugin's own ``server_module serve --policy POLICY``."""
        if self.served is not None:
            return ["-m", "conflictbench_serving", self.name]
        return ["-m", self.server_module, "serve", "--policy", self.name]

    @classmethod
    def model_python(cls, cfg: HostedConfig, name: str = "") -> Path:
        """The interpreter that runs the server: ``model.python``, or the model environment set-up made; checked
        to host policy ``name`` (its plugin installed there)."""
        environment = cls.model_environment_name()
        python = Path(cfg.python).expanduser() if cfg.python else model_environment(environment) / "bin" / "python"
        setup = f"`scripts/setup.sh --models {environment}`"
        if not python.exists():
            raise UserError(
                f"no model environment at {python}: build it with {setup}, or point model.python= at a Python with "
                f"the plugin's server half (`pip install ./serving ./plugins/{environment}/server` in a checkout)"
            )
        if cls.served is not None:
            probe = f"from conflictbench_serving.command import served_model; served_model({name!r})"
        else:
            probe = f"import {cls.server_module}"
        probe_environment(python, probe, cfg.device, f"the {environment} server", setup)
        return python

    def _environment_stack(self, python: Path | None) -> dict[str, Any] | str:
        """The model stack of the environment the server will run in, as its probe said it (``model_python``): the
        device kind and every distribution's version; ``unreported`` where not known."""
        stack, device = probed_stack(python, self.cfg.device)
        if device is not None:
            self.device = device
        return stack

    def start(self) -> None:
        if self.checkpoint is None or self.client is not None:
            return
        self.server, url = self._start_server(self.python or self.model_python(self.cfg, self.name))
        try:
            self.metadata = self._connect(dataclasses.replace(self.cfg, server=url))
        except BaseException:
            self.close()
            raise
        if self.metadata.get("checkpoint_fingerprint", self.identity["checkpoint"]) != self.identity["checkpoint"]:
            self.close()
            raise UserError(f"the checkpoint at {self.checkpoint} changed while its server was loading it")
        reported, counted = self.metadata.get("model_stack"), self.identity.get("model_stack")
        if reported is not None and isinstance(counted, dict) and reported != counted:
            self.close()
            raise UserError(
                f"the {self.name} server started for this run runs on another stack than its environment's files "
                f"said ({stack_difference(counted, reported)}): its episodes would be stored under the wrong identity"
            )
        if self.served is not None and self._reads_metadata:  # conflictbench-serve says both: an impostor could not
            for field, what in (("checkpoint_fingerprint", "which checkpoint"), ("model_stack", "what model stack")):
                if self.metadata.get(field) is None:
                    self.close()
                    raise UserError(
                        f"the {self.name} server started for this run does not say {what} it loaded (no {field} "
                        f"in its metadata; conflictbench-serve says it): its answers cannot be counted as "
                        f"{self.checkpoint}'s"
                    )

    def _start_server(self, python: Path) -> tuple[ServerProcess, str]:
        reports = self.served is not None  # conflictbench-serve says where it listens; a former server_module not
        port = 0 if reports else free_port()
        argv = [str(python), *self.server_command(), "--checkpoint", str(self.checkpoint)]
        argv += ["--host", "127.0.0.1", "--port", str(port), "--device", self.device]
        argv += ["--max-batch", str(self.cfg.max_batch)]
        env: dict[str, str | None] = {key: value for key, value in MODEL_PROCESS_ENV.items() if key not in os.environ}
        # Never the user's token for another server: a fresh one for this server, where every request carries it.
        self.token = secrets.token_urlsafe(32) if reports and self._sends_token() else None
        env[TOKEN_VARIABLE] = self.token
        server = ServerProcess(
            argv,
            name=self.model_environment_name(),
            health_url="" if reports else f"http://127.0.0.1:{port}/healthz",
            ready=None if reports else self.ready_check(f"{self.url_scheme}://127.0.0.1:{port}"),
            env=env,
            startup_timeout_s=self.cfg.startup_timeout_s,
            reports_address=reports,
        )
        print(
            f"conflictbench: starting the {self.name} server for {self.checkpoint} (log: {server.log_path})",
            file=sys.stderr,
        )
        if not reports:
            print(
                f"conflictbench: warning: the {self.name} server is started the former way (server_module, until "
                "0.4.0): the run cannot prove that what answers on its port is that server; declare served "
                "(conflictbench-serve reports the port it bound)",
                file=sys.stderr,
            )
        server.start()
        if reports:
            port = server.address[1]
        return server, f"{self.url_scheme}://127.0.0.1:{port}"

    def _connect(self, cfg: HostedConfig) -> dict[str, Any]:
        """Connect to ``cfg.server`` and return what it says about itself (its metadata, maybe empty)."""
        client = PolicyClient.from_config(cfg, transport=self._transport)
        try:
            transport = client.open()
            self._reads_metadata = hasattr(transport, "metadata")  # a protocol without a way to say (plain JSON): none
            metadata = dict(getattr(transport, "metadata", None) or {})
            hosted, wanted = metadata.get("policy_type"), self.policy_types.get(self.name)
            if hosted is not None and wanted is not None and hosted != wanted:
                raise UserError(f"the server at {cfg.server} hosts a {hosted} policy, not {self.name}")
        except BaseException:
            client.close()
            raise
        self.client = client
        return metadata

    def _transport(self, url: str) -> Transport:
        """A connection's transport; to a started server, one that ends with it: once it has exited, another
        process may hold its port."""
        transport = self.make_transport(url)
        return StartedServerConnection(transport, self.server) if self.server is not None else transport

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
