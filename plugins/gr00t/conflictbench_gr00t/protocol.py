"""NVIDIA Isaac-GR00T's inference protocol: ZeroMQ REQ/REP, msgpack, numpy arrays as ``np.save`` bytes.

The facts, from Isaac-GR00T's ``gr00t/policy/server_client.py`` (``PolicyServer``, ``PolicyClient``,
``MsgSerializer``) and ``gr00t/policy/gr00t_policy.py`` (``Gr00tSimPolicyWrapper``, which
``run_gr00t_server.py --use-sim-policy-wrapper`` serves to its LIBERO client):

- one request, one reply, each a msgpack map; an array is the map ``{"__ndarray_class__": True,
  "as_npy": <the bytes np.save writes, allow_pickle=False>}`` (dtype and shape travel inside the .npy
  header); arrays of object dtype cannot be sent;
- a request is ``{"endpoint": NAME, "data": {...}}`` (``data`` left out for endpoints without input), plus
  ``"api_token"`` when the server wants one; endpoints ``ping``, ``get_action``, ``reset``,
  ``get_modality_config``, ``kill``;
- ``get_action`` takes ``{"observation": obs, "options": options}`` and answers ``[action, info]``: the
  sim wrapper's flat layout, ``video.<camera>`` uint8 (B, T, H, W, C), ``state.<name>`` float32 (B, T, D),
  the language key with a list of B strings, and back ``action.<name>`` float32 (B, T, D);
- any failure answers ``{"error": message}`` (an unknown endpoint: ``"Unknown endpoint: NAME"``).

Our additions, which NVIDIA's server ignores: the per-request sampling seed inside ``options`` (its
policies take ``options`` and leave it unused), and the endpoint ``conflictbench_metadata`` (what our server
hosts: policy type, checkpoint fingerprint, batch shape), which NVIDIA's server answers with its unknown
endpoint error. This module imports neither conflictbench nor torch: the model environment's server uses it.
"""

from __future__ import annotations

import io
from typing import Any

import msgpack
import numpy as np

from conflictbench_serving.checkpoints import NOISE_SEED
from conflictbench_serving.requests import describe, is_noise_seed

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

GET_ACTION, PING, METADATA = "get_action", "ping", "conflictbench_metadata"
#: Our one addition to a request's ``options``: the seed of this request's sampling noise, in [0, 2**63)
#: (``NOISE_SEED``, conflictbench-serving's convention for every server).
ERROR = "error"

_ARRAY_TAG = "__ndarray_class__"


class InvalidRequest(ValueError):
    """A request that is not a GR00T LIBERO observation; the message is sent back as the error."""


def _encode(value: Any) -> Any:
    if isinstance(value, np.generic):  # a numpy scalar travels as the plain number it is
        return value.item()
    if isinstance(value, np.ndarray):
        if value.dtype.kind == "O":
            raise TypeError("arrays of object dtype cannot be sent")
        buffer = io.BytesIO()
        np.save(buffer, value, allow_pickle=False)
        return {_ARRAY_TAG: True, "as_npy": buffer.getvalue()}
    return value


def _decode(obj: dict) -> Any:
    if _ARRAY_TAG in obj:
        return np.load(io.BytesIO(obj["as_npy"]), allow_pickle=False)
    return obj


def packb(obj: Any) -> bytes:
    """``obj`` (maps, lists, strings, numbers, numpy arrays) as one GR00T message."""
    return msgpack.packb(obj, default=_encode)


def unpackb(data: bytes) -> Any:
    """The value in one GR00T message (arrays come back as writable arrays)."""
    return msgpack.unpackb(data, object_hook=_decode)


def get_action_request(observation: dict, seed: int | None = None, api_token: str | None = None) -> dict:
    """The ``get_action`` request for ``observation``, with our sampling seed in ``options``."""
    request: dict[str, Any] = {
        "endpoint": GET_ACTION,
        "data": {"observation": observation, "options": None if seed is None else {NOISE_SEED: seed}},
    }
    if api_token:
        request["api_token"] = api_token
    return request


def endpoint_request(endpoint: str, api_token: str | None = None) -> dict:
    """A request for an endpoint without input (``ping``, ``conflictbench_metadata``)."""
    return {"endpoint": endpoint, **({"api_token": api_token} if api_token else {})}


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
