"""NVIDIA Isaac-GR00T's inference protocol for LIBERO: what a ``get_action`` request and its reply hold.

The framing (ZeroMQ REQ/REP, msgpack, numpy arrays as ``np.save`` bytes, ``{"endpoint", "data"}`` requests,
``{"error": message}`` failures) is conflictbench-serving's :mod:`conflictbench_serving.zeromq` (its codec and
names are re-exported here) and, client side, ``conflictbench.hosting.zeromq``. The facts, from Isaac-GR00T's
``gr00t/policy/gr00t_policy.py`` (``Gr00tSimPolicyWrapper``, which ``run_gr00t_server.py
--use-sim-policy-wrapper`` serves to its LIBERO client):

- ``get_action`` takes ``{"observation": obs, "options": options}`` and answers ``[action, info]``: the
  sim wrapper's flat layout, ``video.<camera>`` uint8 (B, T, H, W, C), ``state.<name>`` float32 (B, T, D),
  the language key with a list of B strings, and back ``action.<name>`` float32 (B, T, D).

Our additions, which NVIDIA's server ignores: the per-request sampling seed inside ``options`` (its
policies take ``options`` and leave it unused), and the endpoint ``conflictbench_metadata`` (what our server
hosts: policy type, checkpoint fingerprint, batch shape), which NVIDIA's server answers with its unknown
endpoint error. This module imports neither conflictbench nor torch: the model environment's server uses it.

The wire is ``n1.7-release``'s (``23ace64``), usable up to but not including ``3df8b38`` (2026-05-07). From
``3df8b38`` on, NVIDIA's main branch encodes arrays with msgpack_numpy and its decoder no longer reads
``__ndarray_class__`` maps (``server_client.py:50-55``, ``:99-112`` at ``626af89``): our arrays would reach its
policy as maps and every ``get_action`` fail. The two are told apart by a ``get_modality_config`` reply
(:func:`speaks_msgpack_numpy`), a request NVIDIA's own ``PolicyClient`` sends (``server_client.py:260-261`` at
``23ace64``; ``examples/DROID/main_gr00t.py:149``) and its server answers with the policy's modality configs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench_serving.checkpoints import NOISE_SEED
from conflictbench_serving.requests import describe, is_noise_seed
from conflictbench_serving.zeromq import (
    ERROR,
    GET_ACTION,
    METADATA,
    PING,
    InvalidRequest,
    endpoint_request,
    packb,
    unpackb,
)

__all__ = [  # the framing's names, re-exported: this protocol's codec and endpoints
    "ERROR",
    "GET_ACTION",
    "METADATA",
    "PING",
    "InvalidRequest",
    "endpoint_request",
    "packb",
    "unpackb",
    "get_action_request",
    "request_seed",
    "speaks_msgpack_numpy",
    "validate_observation",
]

#: The sim wrapper's flat observation keys for LIBERO (``gr00t/eval/sim/LIBERO/libero_env.py``).
VIDEO_KEYS = ("video.image", "video.wrist_image")
STATE_KEYS = ("state.x", "state.y", "state.z", "state.roll", "state.pitch", "state.yaw", "state.gripper")
#: Width of each state key: one number each, two gripper joint positions.
STATE_WIDTHS = {key: 2 if key == "state.gripper" else 1 for key in STATE_KEYS}
LANGUAGE_KEY = "annotation.human.action.task_description"
#: Action keys concatenated, in this order, to LIBERO's 7-D action.
ACTION_KEYS = ("action.x", "action.y", "action.z", "action.roll", "action.pitch", "action.yaw", "action.gripper")
#: LIBERO renders 256 x 256 and GR00T's LIBERO client sends the images at that size.
IMAGE_SIZE = 256
#: NVIDIA's endpoint answering the policy's ``ModalityConfig`` per modality (ours answers ``{}``).
MODALITY_CONFIG = "get_modality_config"
#: How a ``ModalityConfig`` is marked on the wire: ``n1.7-release`` (``server_client.py:43``, ``:51-55`` at
#: ``23ace64``) and main since ``3df8b38`` (``server_client.py:93-96``, ``:104`` at ``626af89``).
RELEASE_MODALITY_MARK, MAIN_MODALITY_MARK = "__ModalityConfig_class__", "__ModalityConfig__"
#: The one revision this client is audited against; the wire it speaks holds up to ``3df8b38``, not included.
RELEASE_TAG, RELEASE_COMMIT = "n1.7-release", "23ace64f17aa5015259b8609d371eb61a357c776"


def get_action_request(observation: dict, seed: int | None = None, api_token: str | None = None) -> dict:
    """The ``get_action`` request for ``observation``, with our sampling seed in ``options`` (``NOISE_SEED``, an
    int in [0, 2**63): conflictbench-serving's convention for every server, which NVIDIA's ignores)."""
    request: dict[str, Any] = {
        "endpoint": GET_ACTION,
        "data": {"observation": observation, "options": None if seed is None else {NOISE_SEED: seed}},
    }
    if api_token:
        request["api_token"] = api_token
    return request


def speaks_msgpack_numpy(modality_config: Any) -> bool:
    """Whether a ``get_modality_config`` reply comes from a server of Isaac-GR00T's main branch since ``3df8b38``,
    whose msgpack_numpy decoder cannot read our arrays (any other reply, an error included, says nothing)."""
    if not isinstance(modality_config, dict):
        return False
    return any(isinstance(value, dict) and MAIN_MODALITY_MARK in value for value in modality_config.values())


def validate_observation(observation: Any) -> int:
    """The batch size of ``observation`` if it is a valid LIBERO observation, else :class:`InvalidRequest`."""
    if not isinstance(observation, dict):
        raise InvalidRequest(f"an observation must be a map, got {type(observation).__name__}")
    batch = None
    for key in (*VIDEO_KEYS, *STATE_KEYS):
        value = observation.get(key)
        if value is None:
            raise InvalidRequest(f"missing {key!r}")
        video = key in VIDEO_KEYS
        wanted = "uint8 (B, 1, 256, 256, 3)" if video else f"float32 (B, 1, {STATE_WIDTHS.get(key)})"
        good = isinstance(value, np.ndarray) and (
            (video and value.dtype == np.uint8 and value.shape[1:] == (1, IMAGE_SIZE, IMAGE_SIZE, 3))
            or (not video and value.dtype == np.float32 and value.shape[1:] == (1, STATE_WIDTHS[key]))
        )
        if good and not video and not np.all(np.isfinite(value)):
            good = False
        if not good:
            raise InvalidRequest(f"{key!r} must be {wanted}, got {describe(value)}")
        if batch is None:
            batch = len(value)
        elif len(value) != batch:
            raise InvalidRequest(f"{key!r} has batch size {len(value)}, others {batch}")
    language = observation.get(LANGUAGE_KEY)
    texts = isinstance(language, (list, tuple)) and all(isinstance(text, str) for text in language)
    if not texts or len(language) != batch:
        raise InvalidRequest(f"{LANGUAGE_KEY!r} must be a list of {batch} strings, got {describe(language)}")
    if not batch:
        raise InvalidRequest("an observation must hold at least one row")
    return batch


def request_seed(options: Any) -> int | None:
    """The sampling seed in a request's ``options`` (None if absent); :class:`InvalidRequest` if malformed."""
    if not isinstance(options, dict) or NOISE_SEED not in options:
        return None
    seed = options[NOISE_SEED]
    if not is_noise_seed(seed):
        raise InvalidRequest(f"options[{NOISE_SEED!r}] must be an int in [0, 2**63), got {describe(seed)}")
    return seed
