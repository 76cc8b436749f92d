"""UniVLA's inference protocol, ours: upstream runs UniVLA in-process only and has no server.

It follows OpenVLA's ``deploy.py`` (REST ``POST /act``, json-numpy bodies, ``conflictbench.hosting.rest``'s
transport) with what UniVLA's split needs. The server is stateless; the client keeps each episode's latent
history and ensembling window:

- request ``{"image": uint8 224 x 224 x 3 (processed as OpenVLA's client does), "instruction": text, "history":
  the previous query's latent tokens as text ("" at an episode's first query), "unnorm_key": key,
  "conflictbench/noise_seed": int}``;
- reply ``{"actions": float64 (window, 7), the action decoder's normalized chunk, "latent_tokens": int64 (<= 4,),
  what upstream's ``predict_latent_action`` returns as ids: the last four ids above 32000 of the whole sequence,
  prompt included (OpenDriveLab/UniVLA@0ab9e9d ``prismatic/extern/hf/modeling_prismatic.py:561-567``). Where the
  model sampled other tokens, ids of the prompt's history fill the gap; fewer than four come back only where the
  prompt holds too few, as at an episode's first query. Our server calls that function, so these are upstream's
  ids; the client writes them into the next prompt's history as upstream's loop does}``;
- ``GET /metadata``: ``policy_type`` "univla", ``checkpoint_fingerprint``, ``max_batch``, ``window`` and
  ``action_statistics`` (per key: ``q01``, ``q99``, ``mask``), with which the client un-normalizes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from conflictbench_serving.checkpoints import NOISE_SEED, NOISE_SEED_LIMIT

from .processing import LATENT_TOKENS

__all__ = ["NOISE_SEED", "NOISE_SEED_LIMIT", "act_request", "read_reply"]


def act_request(image: np.ndarray, instruction: str, history: str, unnorm_key: str, seed: int) -> dict[str, Any]:
    return {
        "image": np.ascontiguousarray(image, dtype=np.uint8),
        "instruction": instruction,
        "history": history,
        "unnorm_key": unnorm_key,
        NOISE_SEED: int(seed),
    }


def read_reply(reply: Any, window: int) -> tuple[np.ndarray, np.ndarray]:
    """The normalized chunk (window, 7) and the latent token ids (4,) of a reply; ValueError if it is neither."""
    if not isinstance(reply, dict) or "actions" not in reply or "latent_tokens" not in reply:
        raise ValueError("expected a reply with 'actions' and 'latent_tokens'")
    chunk = np.array(reply["actions"], dtype=np.float64)
    tokens = np.array(reply["latent_tokens"], dtype=np.int64)
    if chunk.shape != (window, 7) or tokens.ndim != 1 or len(tokens) > LATENT_TOKENS:
        raise ValueError(
            f"expected actions ({window}, 7) and up to 4 latent tokens, got {chunk.shape} and {tokens.shape}"
        )
    return chunk, tokens
