"""Per-request sampling noise for models whose library draws it for the whole batch (model environment only).

LeRobot's VLA-JEPA and GR00T N1.7 ignore any ``noise=`` and draw one ``torch.randn(B, horizon, dim)`` inside
their action head, so a row's noise would be a slice of a draw shared with its batch company: its actions would
depend on which requests happened to share its call. :func:`seeded_draw` hands that one draw each row's own
noise instead, drawn from a CPU generator seeded with the row's seed (:func:`row_noise`), by standing in for
the head module's ``torch`` for the duration of the call. A call in which the head does not draw exactly once,
or draws another shape, fails: a library that samples otherwise cannot be seeded per request this way, and
results must not quietly lose their reproducibility.

Imports torch only when called.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from types import ModuleType
from typing import Any

from .checkpoints import reduce_seed


def row_noise(seed: int | None, shape: Sequence[int]):
    """One row's noise: standard normal float32 of ``shape`` from a CPU generator seeded with ``seed``
    (None: the default seed). The same draw as ``torch.manual_seed(seed); torch.randn((1, *shape))[0]``."""
    import torch

    generator = torch.Generator(device="cpu").manual_seed(reduce_seed(seed))
    return torch.randn(tuple(shape), generator=generator, dtype=torch.float32)


class _OneDraw:
    """A module's ``torch`` during one call: ``randn`` answers the prepared noise, once; the rest is torch's."""

    def __init__(self, torch_module: Any, noise: Any) -> None:
        self._torch, self._noise, self.draws = torch_module, noise, 0

    def randn(self, *size: Any, dtype: Any = None, device: Any = None, **kwargs: Any) -> Any:
        if "size" in kwargs:
            size = (kwargs.pop("size"),)
        shape = tuple(size[0]) if len(size) == 1 and isinstance(size[0], (tuple, list)) else tuple(size)
        self.draws += 1
        if shape != tuple(self._noise.shape) or self.draws > 1:
            raise RuntimeError(
                f"the action head drew noise of shape {shape} (draw {self.draws}); expected one draw of "
                f"{tuple(self._noise.shape)}: this library samples otherwise, and cannot be seeded per request"
            )
        return self._noise.to(device=device, dtype=dtype)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._torch, name)


@contextmanager
def seeded_draw(module: ModuleType, noise: Any) -> Iterator[None]:
    """Within the block, ``module``'s one ``torch.randn`` answers ``noise`` (stacked per-row noise, the draw's
    exact shape); RuntimeError if the block ends without exactly that one draw."""
    real = module.torch
    stand_in = _OneDraw(real, noise)
    module.torch = stand_in
    try:
        yield
    finally:
        module.torch = real
    if stand_in.draws != 1:
        raise RuntimeError(
            f"the action head drew noise {stand_in.draws} times, not once: it cannot be seeded per request"
        )
