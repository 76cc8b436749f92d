"""What every hosted checkpoint shares: its content digest, where it may run, and the request seed rule.

A request's sampling seed travels in the request as ``NOISE_SEED`` (our one addition to each upstream
format: their servers ignore it): an int in [0, 2**63), which fits a signed 64-bit integer everywhere.
A server seeds the request's noise with it, so an episode's actions depend on the episode and step, never
on the call order or the batch company.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from pathlib import Path

#: Where a checkpoint can be loaded (``model.device``, ``serve --device``).
DEVICE = re.compile(r"auto|cpu|cuda(:\d+)?")
NOISE_SEED = "conflictbench/noise_seed"
NOISE_SEED_LIMIT = 2**63
#: Seeds reduce to torch's seed range; a request without one samples with seed 0.
SEED_MODULUS = 2**64
DEFAULT_SEED = 0


def fingerprint(files: Iterable[Path]) -> str:
    """A digest of ``files`` by name and content: the same weights under another path give the same digest,
    new weights written to the same path another. Reads every byte (a 7 GB checkpoint: seconds)."""
    digest = hashlib.sha256()
    for path in files:
        digest.update(f"{Path(path).name}\0".encode())
        with open(path, "rb") as handle:
            digest.update(hashlib.file_digest(handle, "sha256").digest())
    return f"sha256:{digest.hexdigest()[:24]}"


def reduce_seed(seed: object) -> int:
    """A request's seed (None: the default) in torch's seed range."""
    return (DEFAULT_SEED if seed is None else int(seed)) % SEED_MODULUS


class CheckpointError(Exception):
    """The folder is not a usable checkpoint of the model (the message is one line for the user)."""
