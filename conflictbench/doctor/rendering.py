"""The rendering check: this machine's frames of both cameras against the goldens', pixel for pixel.

Only frames of the same renderer family can be compared that way (Mesa's llvmpipe and an NVIDIA driver rasterize
and filter differently); against another family the difference is reported and the check does not fail.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from conflictbench.sim.libero_env import CAMERAS

from .checks import Check
from .goldens import Goldens
from .replaying import Replayed


@dataclass(frozen=True)
class FrameDifference:
    camera: str
    pixels: int  # pixels with any channel different (all of them when the sizes differ)
    total: int
    max_abs: int  # the largest channel difference (255 when the sizes differ)

    @property
    def identical(self) -> bool:
        return self.pixels == 0


def frame_difference(camera: str, frame: np.ndarray, golden: np.ndarray) -> FrameDifference:
    if frame.shape != golden.shape:
        return FrameDifference(camera, golden.shape[0] * golden.shape[1], golden.shape[0] * golden.shape[1], 255)
    delta = np.abs(frame.astype(np.int16) - golden.astype(np.int16))
    return FrameDifference(camera, int(np.count_nonzero(delta.max(axis=-1))), delta.shape[0] * delta.shape[1],
                           int(delta.max(initial=0)))  # fmt: skip


def compare_frames(replays: Sequence[Replayed], goldens: Goldens) -> list[FrameDifference]:
    """Every golden frame against this machine's (a frame not rendered here counts as wholly different)."""
    out = []
    by_name = {r.name: r for r in replays}
    for episode in goldens.episodes:
        replayed = by_name.get(episode.name)
        for state in episode.frame_states:
            for camera in CAMERAS:
                golden = goldens.frame(episode.name, camera, state)
                frame = replayed.frames.get((camera, state)) if replayed else None
                out.append(frame_difference(camera, np.zeros((0, 0, 3), np.uint8) if frame is None else frame, golden))
    return out


def rendering_passes(all_identical: bool, same_family: bool) -> bool:
    """Identical frames pass; so does another renderer family, whose pixels are not expected to match."""
    return all_identical or not same_family


def rendering_check(differences: Sequence[FrameDifference], this_family: str, golden_family: str) -> Check:
    same_family = this_family == golden_family
    parts = []
    for camera in CAMERAS:
        mine = [d for d in differences if d.camera == camera]
        differing = [d for d in mine if not d.identical]
        if not differing:
            parts.append(f"{camera} identical ({len(mine)} frames)")
        else:
            share = sum(d.pixels for d in differing) / max(1, sum(d.total for d in differing))
            parts.append(f"{camera} differs in {len(differing)}/{len(mine)} frames ({share:.1%} of their pixels, "
                         f"max |Δ| {max(d.max_abs for d in differing)})")  # fmt: skip
    identical = all(d.identical for d in differences)
    if same_family:
        said = f"renderer {this_family}, as the goldens'"
    else:
        said = (f"renderer {this_family}, the goldens' {golden_family}: frames from different renderers are not "
                "comparable pixel for pixel, so this is no failure")  # fmt: skip
    return Check("rendering", rendering_passes(identical, same_family), f"{'; '.join(parts)}; {said}")
