"""What every server's request check shares: the seed rule and how a bad value is described in its error."""

from __future__ import annotations

from typing import Any

import numpy as np

from .checkpoints import NOISE_SEED_LIMIT


def is_noise_seed(value: Any) -> bool:
    """Whether ``value`` is a valid ``NOISE_SEED``: an int (not a bool) in [0, 2**63)."""
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and 0 <= int(value) < NOISE_SEED_LIMIT


def describe(value: Any) -> str:
    """A short description of a value for an error message (an array by dtype and shape, else type and repr)."""
    if isinstance(value, np.ndarray):
        return f"{value.dtype} array of shape {value.shape}"
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"
