"""VLA-JEPA's inference protocol: starVLA's websocket policy server, on openpi's wire format.

The facts, from the server and client tools VLA-JEPA ships (``deployment/model_server/tools/
websocket_policy_server.py`` and ``websocket_policy_client.py``, starVLA's, adapted from openpi's):

- a websocket; the server's first frame is its packed metadata (``{"env": "simpler_env"}`` upstream); every
  frame is openpi's msgpack-numpy (read and written with conflictbench-serving's codec);
- a request is ``{"payload": {...}, "type": "infer"}`` as upstream's client packs it (``request_id`` optional; ``type``
  ``ping`` answers at once);
  the LIBERO client's payload holds ``batch_images`` (a list per batch row of its camera images, uint8),
  ``instructions`` (a list of texts), ``state`` (a list per row of an (1, 8) array), ``unnorm_key``,
  ``do_sample`` (False), ``use_ddim`` (True) and ``num_ddim_steps`` (10), all passed to the model's
  ``predict_action(**payload)`` (which takes ``**kwargs``: a key it does not know is ignored);
- the reply is ``{"status": "ok", "ok": True, "type": "inference_result", "request_id": ID, "data":
  {"normalized_actions": (B, chunk, 7)}}``; a failure the server catches is the same map with ``"status":
  "error"`` and ``"error": {"message": ...}``; one it does not is a text frame and close code 1011.

Our additions: the seed of this request's sampling noise in the payload, ``conflictbench/noise_seed``, and the
envelope's ``request_id`` after upstream's two keys (its server reads both by name and echoes the id).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from conflictbench_serving.checkpoints import NOISE_SEED, NOISE_SEED_LIMIT
from conflictbench_serving.msgpack_numpy import packb, unpackb
from conflictbench_serving.requests import describe, is_noise_seed

__all__ = [
    "NOISE_SEED",
    "NOISE_SEED_LIMIT",
    "InvalidRequest",
    "ReplyError",
    "Row",
    "infer_request",
    "normalized_actions",
    "packb",
    "reply",
    "request_rows",
    "unpackb",
]

#: The LIBERO client's fixed inference options (``examples/LIBERO/model2libero_interface.py``).
DO_SAMPLE, USE_DDIM, NUM_DDIM_STEPS = False, True, 10


class ReplyError(Exception):
    """The server answered with an error (``"status": "error"``): not the model's behaviour."""


def infer_request(
    images: list[np.ndarray], instruction: str, state: np.ndarray, request_id: str, unnorm_key: str | None, seed: int
) -> dict:
    """One ``infer`` request for one batch row, laid out as VLA-JEPA's LIBERO client lays it out."""
    payload = {
        "batch_images": [list(images)],
        "instructions": [instruction],
        "unnorm_key": unnorm_key,
        "do_sample": DO_SAMPLE,
        "use_ddim": USE_DDIM,
        "num_ddim_steps": NUM_DDIM_STEPS,
        "state": [np.asarray(state, dtype=np.float64)[None]],
        NOISE_SEED: seed,
    }
    # Upstream's envelope and key order (websocket_policy_client.py:72-76 at ec8c70f), then our request id.
    return {"payload": payload, "type": "infer", "request_id": request_id}


def normalized_actions(reply: Any) -> np.ndarray:
    """The first row's normalized chunk (chunk, D) of an ``inference_result``, in the dtype it came in;
    :class:`ReplyError` for an error."""
    if not isinstance(reply, dict):
        raise ValueError(f"a reply is a map, got {type(reply).__name__}")
    if reply.get("status") == "error" or reply.get("ok") is False:
        error = reply.get("error")
        message = error.get("message") if isinstance(error, dict) else error
        raise ReplyError(str(message or "no message"))
    # Its own dtype (float32 from a server): upstream's client un-normalizes in it, so ours does too.
    actions = np.asarray(reply["data"]["normalized_actions"])
    if actions.dtype.kind not in "fiu":
        raise ValueError(f"normalized_actions must be numbers, got dtype {actions.dtype}")
    if actions.ndim != 3 or actions.shape[0] < 1 or actions.shape[1] < 1:
        raise ValueError(f"normalized_actions has shape {actions.shape}, expected (B, chunk, D)")
    return actions[0]


# The server side (ours, in the model environment) ------------------------------------------------------

#: What VLA-JEPA's LIBERO client sends: two upright 224-px images per row and LIBERO's 8-D state.
IMAGE_SHAPE = (224, 224, 3)
STATE_SIZE = 8


class InvalidRequest(ValueError):
    """A request that is not a VLA-JEPA LIBERO request; the message goes back in an error reply."""


@dataclass(frozen=True)
class Row:
    """One batch row of an ``infer`` payload, checked: what the model needs of it."""

    image: np.ndarray
    wrist_image: np.ndarray
    state: np.ndarray
    instruction: str
    seed: int | None


def request_rows(payload: Any) -> list[Row]:
    """The rows of an ``infer`` payload, each checked; :class:`InvalidRequest` saying what is wrong otherwise.

    A row's seed is the payload's ``NOISE_SEED`` (the same for every row; None when absent)."""
    if not isinstance(payload, dict):
        raise InvalidRequest(f"the payload must be a map, got {describe(payload)}")
    for key in ("batch_images", "instructions", "state"):
        if not isinstance(payload.get(key), (list, tuple)):
            raise InvalidRequest(f"{key!r} must be a list (one entry per batch row), got {describe(payload.get(key))}")
    images, instructions, states = payload["batch_images"], payload["instructions"], payload["state"]
    if not len(images) == len(instructions) == len(states) >= 1:
        lengths = f"{len(images)}, {len(instructions)}, {len(states)}"
        raise InvalidRequest(f"'batch_images', 'instructions' and 'state' need the same number of rows, got {lengths}")
    seed = payload.get(NOISE_SEED)
    if seed is not None and not is_noise_seed(seed):
        raise InvalidRequest(f"{NOISE_SEED!r} must be an int in [0, 2**63), got {describe(seed)}")
    rows = []
    for index, (cameras, instruction, state) in enumerate(zip(images, instructions, states, strict=True)):
        if not isinstance(cameras, (list, tuple)) or len(cameras) != 2:
            raise InvalidRequest(f"row {index}: 'batch_images' must hold 2 images (agentview, wrist)")
        for image in cameras:
            if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.shape != IMAGE_SHAPE:
                raise InvalidRequest(f"row {index}: images must be uint8 arrays of shape {IMAGE_SHAPE}, "
                                     f"got {describe(image)}")  # fmt: skip
        state = np.asarray(state) if isinstance(state, (np.ndarray, list, tuple)) else None
        if state is None or state.dtype.kind not in "iuf" or state.size != STATE_SIZE or not np.isfinite(state).all():
            raise InvalidRequest(f"row {index}: 'state' must be {STATE_SIZE} finite numbers")
        if not isinstance(instruction, str):
            raise InvalidRequest(f"row {index}: the instruction must be a string, got {describe(instruction)}")
        rows.append(Row(cameras[0], cameras[1], state.reshape(STATE_SIZE).astype(np.float32), instruction,
                        None if seed is None else int(seed)))  # fmt: skip
    return rows


def reply(kind: str, request_id: Any, data: dict | None = None, error: str | None = None) -> dict:
    """A reply as starVLA's server shapes it: ``status``/``ok``, the ``type``, the ``request_id``, then
    ``data`` or ``error: {"message"}``."""
    if error is not None:
        return {"status": "error", "ok": False, "type": kind, "request_id": request_id, "error": {"message": error}}
    return {"status": "ok", "ok": True, "type": kind, "request_id": request_id, **({"data": data} if data else {})}
