"""Frames into a video file a browser plays: H.264 in MP4 (every current browser), through PyAV.

The file is written under a temporary name and renamed when whole, so an interrupted render never leaves a
video that looks finished.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FPS = 20  # LIBERO's control rate: one frame per executed action plays in real time


@dataclass
class Mp4Sink:
    """A :class:`conflictbench.sim.replay.FrameSink` writing ``path`` (picklable until opened)."""

    path: str
    fps: int = FPS
    crf: int = 28  # x264's quality scale (lower: better, larger); 28 keeps a 256-px rollout near 100-300 KB

    def __post_init__(self) -> None:
        self._container: Any = None
        self._stream: Any = None

    def __getstate__(self) -> dict:
        return {"path": self.path, "fps": self.fps, "crf": self.crf}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.__post_init__()

    @property
    def _temporary(self) -> Path:
        return Path(self.path).with_name(f".{Path(self.path).name}.{os.getpid()}.tmp")

    def open(self) -> None:
        import av

        Path(self.path).parent.mkdir(parents=True, exist_ok=True)
        self._temporary.unlink(missing_ok=True)  # a link left at this name (a site copied in) is never written through
        self._container = av.open(str(self._temporary), mode="w", format="mp4", options={"movflags": "+faststart"})
        self._stream = None

    def add(self, frame: np.ndarray) -> None:
        import av

        if self._stream is None:  # the first frame fixes the size
            height, width = frame.shape[:2]
            self._stream = self._container.add_stream("libx264", rate=self.fps)
            self._stream.width, self._stream.height = width - width % 2, height - height % 2
            self._stream.pix_fmt = "yuv420p"  # what browsers decode
            self._stream.options = {"crf": str(self.crf), "preset": "medium"}
        image = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame[: self._stream.height, : self._stream.width]),
                                           format="rgb24")  # fmt: skip
        for packet in self._stream.encode(image):
            self._container.mux(packet)

    def abort(self) -> None:
        """A replay that failed: close what is open, keep nothing."""
        try:
            if self._container is not None:
                self._container.close()
        except Exception:  # the encoder's own failure may be why we are here
            pass
        self._temporary.unlink(missing_ok=True)

    def close(self) -> int:
        if self._stream is not None:
            for packet in self._stream.encode():
                self._container.mux(packet)
        self._container.close()
        os.replace(self._temporary, self.path)
        return Path(self.path).stat().st_size
