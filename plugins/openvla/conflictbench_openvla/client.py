"""OpenVLA and OpenVLA-OFT as conflictbench sees them: their LIBERO clients, talking to a ``deploy.py`` server.

``conflictbench model=openvla model.checkpoint=DIR`` starts our server (``conflictbench-serve openvla``, in the
model environment) for a checkpoint folder in Hugging Face format; ``model.server=http://HOST:8000
model.checkpoint=NAME`` plays against a running one, OpenVLA's ``vla-scripts/deploy.py`` or ours;
``model=openvla-oft model.server=http://HOST:8777`` against OpenVLA-OFT's ``deploy.py`` (started with
``--num_images_in_input 2 --unnorm_key <key>``). Upstream splits the work differently for the two, and each
client does exactly what upstream's own does, so that no step runs twice or never:

========================  =====================================  ======================================
step                      OpenVLA (client / deploy.py)           OpenVLA-OFT (client / deploy.py)
========================  =====================================  ======================================
rotate, JPEG, Lanczos     client (agentview)                     client (agentview and wrist)
centre crop               client                                 server
prompt template           server                                 server
proprio                   not used                               client sends raw; server normalizes
unnorm_key                client sends it (per suite)            fixed when the server started
un-normalization          server                                 server
gripper sign and invert   client                                 client
actions per query         1                                      the chunk of 8, open loop (the last
                                                                 ``chunk_length`` of it where fewer)
========================  =====================================  ======================================

``deploy.py`` names no model, so ``model.checkpoint`` names what it hosts; our server says (its checkpoint's
fingerprint). Either is part of every episode's identity.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from conflictbench import HostedConfig, HostedPolicy, Observation, UserError, hookimpl, published_results
from conflictbench.hosting.openvla_family import env_gripper, policy_image, unnorm_key

from .checkpoints import POLICY_TYPE, fingerprint
from .processing import MAX_STEPS
from .protocol import JsonNumpyTransport, oft_request, openvla_request, read_action, read_chunk
from .server import SERVED

OFT_CHUNK = 8


@dataclass
class OpenVlaConfig(HostedConfig):
    """Settings of ``openvla`` (``model.<field>=value``; the shared ones are :class:`conflictbench.HostedConfig`'s)."""

    checkpoint: str = ""
    """An OpenVLA checkpoint folder in Hugging Face format (our server is started for it); with ``server``, the
    name of what that server hosts where it does not say (deploy.py), e.g. ``openvla-7b-finetuned-libero-goal``."""
    server: str = ""
    """``http://HOST:PORT`` of a running ``deploy.py`` or ours (``/act`` is added where the URL has no path)."""
    unnorm_key: str = "suite"
    """The statistics the server un-normalizes with: ``suite`` (the episode's LIBERO suite, ``libero_goal``; with
    our server, ``libero_goal_no_noops`` where the checkpoint has only that), ``suite_no_noops``, or a key as it is."""
    center_crop: bool = True
    """Crop the centre 0.9 of the image's area, as OpenVLA's LIBERO evaluation does (``--center_crop True``)."""


@dataclass
class OftConfig(HostedConfig):
    """Settings of ``openvla-oft`` (``model.<field>=value``; shared ones: :class:`conflictbench.HostedConfig`'s)."""

    minimums: ClassVar = {**HostedConfig.minimums, "chunk_length": 1}

    checkpoint: str = ""
    """With ``server``: the name of what that server hosts, with its ``--unnorm_key`` (deploy.py says
    neither), e.g. ``moojink/openvla-7b-oft-finetuned-libero-goal``."""
    server: str = ""
    """``http://HOST:PORT`` of a running OFT ``deploy.py`` (``/act`` is added where the URL has no path)."""
    chunk_length: int = OFT_CHUNK
    """Upstream's ``--num_open_loop_steps`` (OFT's LIBERO value 8, the whole chunk): as upstream's client, the
    LAST ``chunk_length`` actions of each chunk are executed before asking again (its ``deque(maxlen=...)``
    drops the first ones), all of them where the chunk is shorter."""


class _DeployClient(HostedPolicy):
    """What both clients share: deploy.py's transport, the family's step budget and gripper mapping."""

    served = SERVED
    transport = JsonNumpyTransport
    url_scheme = "http"
    default_max_steps = MAX_STEPS
    policy_types = {"openvla": POLICY_TYPE, "openvla-oft": "openvla-oft"}  # our server hosts OpenVLA only
    fingerprint = staticmethod(fingerprint)


class OpenVlaPolicy(_DeployClient):
    """OpenVLA's LIBERO client: the cropped agentview image and the suite's ``unnorm_key``; one action per query."""

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None:
            raise UserError(f"{self.name} needs the agentview camera image")
        image = policy_image(observation.agentview_image, crop=self.cfg.center_crop)
        known = self.metadata.get("unnorm_keys")  # our server says which it has; deploy.py does not
        key = unnorm_key(self.cfg.unnorm_key, observation.suite, known)
        return openvla_request(image, observation.instruction, key)

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        return env_gripper(read_action(reply))


class OftPolicy(_DeployClient):
    """OpenVLA-OFT's LIBERO client: both images resized (not cropped), the raw state; chunks executed open loop."""

    def encode(self, observation: Observation) -> dict[str, Any]:
        if observation.agentview_image is None or observation.wrist_image is None:
            raise UserError(f"{self.name} needs both camera images")
        full = policy_image(observation.agentview_image, crop=False)
        wrist = policy_image(observation.wrist_image, crop=False)
        return oft_request(full, wrist, observation.state, observation.instruction)

    def decode(self, reply: Any, observation: Observation) -> np.ndarray:
        # moojink/openvla-oft@213c5ff run_libero_eval.py:306, :341: deque(maxlen=num_open_loop_steps).extend(chunk)
        # keeps the chunk's last num_open_loop_steps actions (all where it holds fewer), executed in order
        return env_gripper(read_chunk(reply)[-self.cfg.chunk_length :])


POLICIES: dict[str, tuple[type[_DeployClient], type[HostedConfig]]] = {
    "openvla": (OpenVlaPolicy, OpenVlaConfig),
    "openvla-oft": (OftPolicy, OftConfig),
}


def load(name: str, cfg: HostedConfig) -> _DeployClient:
    """The policy for ``model=name``, connected to ``cfg.server``."""
    policy_class, _config = POLICIES[name]
    return policy_class.load(name, cfg)


@hookimpl
def conflictbench_register_policies(register):
    for name, (_policy, config) in POLICIES.items():
        register(name, load=functools.partial(load, name), config=config)


#: What the model's authors published on LIBERO, with its citations (published.toml).
conflictbench_register_published_results = published_results(__package__)
