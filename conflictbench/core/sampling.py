"""Randomness for policies that sample (flow matching noise, token sampling).

A policy's draws must depend on which episode and step it is deciding, never on the order of its
calls: otherwise batched and unbatched play, or one worker and several, give different actions for
the same episode. These functions derive the seed from the episode's ``sampling_key`` (its identity by
settings and versions; ``episode_id`` where none is given) and ``observation.step``, with a hash that is
the same in every process and Python version (``hash()`` is salted per process).
"""

from __future__ import annotations

import hashlib

import numpy as np

from .records import Observation


def sampling_seed(observation: Observation) -> int:
    """A 64-bit seed determined by the episode's identity and the decision's step alone."""
    key = f"{observation.sampling_key or observation.episode_id}\0{observation.step}".encode()
    return int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little")


def rng_for(observation: Observation, *keys: int) -> np.random.Generator:
    """A fresh generator for this decision; ``keys`` mix in further integers (the model's own seed)."""
    return np.random.default_rng([sampling_seed(observation), *(int(k) % 2**64 for k in keys)])
