"""openpi's wire format: msgpack with numpy arrays, over a websocket (both sides use this module).

The facts, from openpi-client's ``msgpack_numpy`` and ``websocket_policy_server`` (PyPI, 0.1.x):

- an array is the map ``{b"__ndarray__": True, b"data": <C-order bytes>, b"dtype": <dtype.str>,
  b"shape": <shape>}``; a numpy scalar is ``{b"__npgeneric__": True, b"data": <item>, b"dtype": ...}``;
  arrays of object, void or complex dtype cannot be sent;
- the server's first frame, on every connection, is the packed metadata map (``{}`` by default);
- each request is one binary frame holding the packed observation map; the reply is one binary frame
  (the packed map with ``actions``), or, when inference raised, a text frame with the traceback,
  after which the server closes the connection (code 1011);
- ``GET /healthz`` answers ``OK`` (readiness without a websocket).

The codec (``packb``/``unpackb``) and the framing are conflictbench-serving's, shared with the other
plugins whose upstream speaks openpi's format.

:func:`validate_request` says what a LIBERO request must hold (our server checks each one with it before
queueing, and the backend before every forward pass). This module imports neither conflictbench nor
torch: the model environment's server uses it too.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench_serving import checkpoints as seeds
from conflictbench_serving.msgpack_numpy import packb as packb  # re-exported: the codec of this protocol
from conflictbench_serving.msgpack_numpy import unpackb as unpackb
from conflictbench_serving.requests import describe, is_noise_seed

#: Request keys of openpi's LIBERO client (``examples/libero/main.py``).
IMAGE = "observation/image"
WRIST_IMAGE = "observation/wrist_image"
STATE = "observation/state"
PROMPT = "prompt"
#: Reply key holding the action chunk (horizon x 7).
ACTIONS = "actions"
#: Our one addition to a request: the seed of the episode's sampling noise at this step (conflictbench-serving's
#: convention). openpi's own LIBERO input transform reads only the four keys above, so its server ignores it.
NOISE_SEED, NOISE_SEED_LIMIT = seeds.NOISE_SEED, seeds.NOISE_SEED_LIMIT
#: What openpi's LIBERO client sends: both images letterboxed to 224, LIBERO's 8-D state.
IMAGE_SHAPE = (224, 224, 3)
STATE_SIZE = 8


class InvalidRequest(ValueError):
    """A request that is not an openpi LIBERO observation; the message is sent to its client."""


def validate_request(request: Any) -> dict:
    """``request`` if it is a valid observation, else :class:`InvalidRequest` saying what is wrong."""
    if not isinstance(request, dict):
        raise InvalidRequest(f"a request must be a map, got {type(request).__name__}")
    for key in (IMAGE, WRIST_IMAGE, STATE, PROMPT):
        if key not in request:
            raise InvalidRequest(f"missing {key!r}")
    for key in (IMAGE, WRIST_IMAGE):
        image = request[key]
        if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.shape != IMAGE_SHAPE:
            raise InvalidRequest(f"{key!r} must be a uint8 array of shape {IMAGE_SHAPE}, got {describe(image)}")
    state = request[STATE]
    try:
        state_array = np.asarray(state)
    except (TypeError, ValueError):
        state_array = None
    if (
        state_array is None
        or state_array.dtype.kind not in "iuf"
        or state_array.shape != (STATE_SIZE,)
        or not np.all(np.isfinite(state_array))
    ):
        raise InvalidRequest(f"{STATE!r} must be {STATE_SIZE} finite numbers, got {describe(state)}")
    if not isinstance(request[PROMPT], str):
        raise InvalidRequest(f"{PROMPT!r} must be a string, got {describe(request[PROMPT])}")
    if NOISE_SEED in request:
        seed = request[NOISE_SEED]
        if not is_noise_seed(seed):
            raise InvalidRequest(f"{NOISE_SEED!r} must be an int in [0, 2**63), got {describe(seed)}")
    return request
