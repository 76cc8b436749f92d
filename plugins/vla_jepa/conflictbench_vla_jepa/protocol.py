"""VLA-JEPA's inference protocol: starVLA's websocket policy server, on openpi's wire format.

The facts, from the server and client tools VLA-JEPA ships (``deployment/model_server/tools/
websocket_policy_server.py`` and ``websocket_policy_client.py``, starVLA's, adapted from openpi's):

- a websocket; the server's first frame is its packed metadata (``{"env": "simpler_env"}`` upstream); every
  frame is openpi's msgpack-numpy (so this plugin reads and writes it with the π plugin's codec);
- a request is ``{"type": "infer", "request_id": ID, "payload": {...}}`` (``type`` ``ping`` answers at once);
  the LIBERO client's payload holds ``batch_images`` (a list per batch row of its camera images, uint8),
  ``instructions`` (a list of texts), ``state`` (a list per row of an (1, 8) array), ``unnorm_key``,
  ``do_sample`` (False), ``use_ddim`` (True) and ``num_ddim_steps`` (10), all passed to the model's
  ``predict_action(**payload)`` (which takes ``**kwargs``: a key it does not know is ignored);
- the reply is ``{"status": "ok", "ok": True, "type": "inference_result", "request_id": ID, "data":
  {"normalized_actions": (B, chunk, 7)}}``; a failure the server catches is the same map with ``"status":
  "error"`` and ``"error": {"message": ...}``; one it does not is a text frame and close code 1011.

Our one addition to the payload: the seed of this request's sampling noise, ``conflictbench/noise_seed``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench_pi0.protocol import NOISE_SEED, NOISE_SEED_LIMIT, packb, unpackb

__all__ = ["NOISE_SEED", "NOISE_SEED_LIMIT", "ReplyError", "infer_request", "normalized_actions", "packb", "unpackb"]

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
    return {"type": "infer", "request_id": request_id, "payload": payload}


def normalized_actions(reply: Any) -> np.ndarray:
    """The first row's normalized chunk (chunk, D) of an ``inference_result``; :class:`ReplyError` for an error."""
    if not isinstance(reply, dict):
        raise ValueError(f"a reply is a map, got {type(reply).__name__}")
    if reply.get("status") == "error" or reply.get("ok") is False:
        error = reply.get("error")
        message = error.get("message") if isinstance(error, dict) else error
        raise ReplyError(str(message or "no message"))
    actions = np.asarray(reply["data"]["normalized_actions"], dtype=np.float64)
    if actions.ndim != 3 or actions.shape[0] < 1 or actions.shape[1] < 1:
        raise ValueError(f"normalized_actions has shape {actions.shape}, expected (B, chunk, D)")
    return actions[0]
