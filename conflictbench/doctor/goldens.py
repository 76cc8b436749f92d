"""The golden episodes ``doctor`` replays: their format, where they are, and which ones fit this stack.

One folder per pinned stack (``py3.11-mujoco2.3.7``): ``goldens.json`` (the stack that made them, its renderer
family, and per episode what to replay and what came of it), ``episodes.npz`` (each episode's executed actions and
end-effector path) and ``frames/<episode>-<camera>-<state>.png`` (both cameras at a few fixed states, lossless).
"""

from __future__ import annotations

import json
import os
import re
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from conflictbench.core import UserError

GOLDENS_ROOT = Path(__file__).parent / "goldens"
#: A folder of goldens to use instead of the shipped ones (one stack's folder, or a root of stack folders).
GOLDENS_VARIABLE = "CONFLICTBENCH_DOCTOR_GOLDENS"
META = "goldens.json"
ARRAYS = "episodes.npz"
FRAMES = "frames"
FORMAT = 1


@dataclass(frozen=True)
class GoldenEpisode:
    name: str
    suite: str
    task_id: int
    init_state: int
    seed: int
    warmup_steps: int
    success_state: int | None
    """The first state (0: after the warm-up; i: after action i) at which the task was solved; None: never."""
    frame_states: tuple[int, ...]


@dataclass
class Goldens:
    folder: Path
    stack_key: str
    stack: dict[str, str]
    renderer_family: str
    image_size: int
    episodes: list[GoldenEpisode]
    actions: dict[str, np.ndarray]
    eef_pos: dict[str, np.ndarray]

    def frame_path(self, episode: str, camera: str, state: int) -> Path:
        return self.folder / FRAMES / f"{episode}-{camera}-{state}.png"

    def frame(self, episode: str, camera: str, state: int) -> np.ndarray:
        from PIL import Image

        with Image.open(self.frame_path(episode, camera, state)) as image:
            return np.asarray(image.convert("RGB"))


def stack_key(python: str, mujoco: str) -> str:
    """``py3.11-mujoco2.3.7``: what the physics of a golden depends on (Python for the seeds, MuJoCo for the rest)."""
    return f"py{python}-mujoco{mujoco}"


def this_stack_key(stack: dict[str, str]) -> str:
    return stack_key(f"{sys.version_info.major}.{sys.version_info.minor}", stack.get("mujoco_version", ""))


def renderer_family(gl_vendor: str, gl_renderer: str) -> str:
    """Which kind of renderer made a frame: the same family renders the same pixels, another does not."""
    vendor, renderer = gl_vendor.lower(), gl_renderer.lower()
    if "llvmpipe" in renderer:
        return "mesa-llvmpipe"
    if "softpipe" in renderer:
        return "mesa-softpipe"
    if "nvidia" in vendor or "nvidia" in renderer:
        return "nvidia"
    if "mesa" in vendor or "mesa" in renderer:
        return "mesa-hardware"
    for name in ("amd", "ati", "intel", "apple"):
        if re.search(rf"\b{name}\b", vendor):
            return "amd" if name == "ati" else name
    return "other"


def write(goldens: Goldens, frames: dict[tuple[str, str, int], np.ndarray]) -> None:
    """Write ``goldens`` (and its frames, by (episode, camera, state)) into its folder, replacing what is there."""
    from PIL import Image

    folder = goldens.folder
    (folder / FRAMES).mkdir(parents=True, exist_ok=True)
    for stale in (folder / FRAMES).glob("*.png"):
        stale.unlink()
    meta = {
        "format": FORMAT,
        "made_by": "scripts/make_goldens.py",
        "stack_key": goldens.stack_key,
        "renderer_family": goldens.renderer_family,
        "image_size": goldens.image_size,
        "stack": goldens.stack,
        "episodes": [asdict(episode) for episode in goldens.episodes],
    }
    (folder / META).write_text(json.dumps(meta, indent=1) + "\n")
    arrays = {f"actions/{name}": a for name, a in goldens.actions.items()}
    arrays |= {f"eef_pos/{name}": p for name, p in goldens.eef_pos.items()}
    np.savez_compressed(folder / ARRAYS, **arrays)
    for (episode, camera, state), frame in frames.items():
        Image.fromarray(frame).save(goldens.frame_path(episode, camera, state), optimize=True)


def read(folder: Path) -> Goldens:
    try:
        meta = json.loads((folder / META).read_text())
        with np.load(folder / ARRAYS) as arrays:
            loaded = {key: arrays[key] for key in arrays.files}
    except (OSError, ValueError) as exc:
        raise UserError(f"cannot read the goldens in {folder}: {exc}") from None
    if meta.get("format") != FORMAT:
        raise UserError(f"the goldens in {folder} are of format {meta.get('format')}, this doctor reads {FORMAT}")
    episodes = [GoldenEpisode(**{**e, "frame_states": tuple(e["frame_states"])}) for e in meta["episodes"]]
    return Goldens(
        folder=folder,
        stack_key=meta["stack_key"],
        stack=meta["stack"],
        renderer_family=meta["renderer_family"],
        image_size=meta["image_size"],
        episodes=episodes,
        actions={e.name: loaded[f"actions/{e.name}"] for e in episodes},
        eef_pos={e.name: loaded[f"eef_pos/{e.name}"] for e in episodes},
    )


def _versions(key: str) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(MuJoCo's version, Python's) of a stack key, as numbers; MuJoCo first: it decides the physics."""
    match = re.fullmatch(r"py([\d.]+)-mujoco([\d.]+)", key)
    if not match:
        return (), ()
    python, mujoco = (tuple(int(part) for part in text.split(".") if part) for text in match.groups())
    return mujoco, python


def nearest(keys: list[str], key: str) -> str:
    """The stack key among ``keys`` closest to ``key``: MuJoCo's version nearest, then Python's."""
    mujoco, python = _versions(key)

    def distance(other: str) -> tuple:
        their_mujoco, their_python = _versions(other)
        return (
            [abs(a - b) for a, b in zip(their_mujoco, mujoco)] or [999],
            [abs(a - b) for a, b in zip(their_python, python)] or [999],
            other,
        )

    return min(keys, key=distance)


def choose(key: str, given: str | None = None) -> tuple[Goldens, bool]:
    """The goldens for the stack ``key`` and whether they were made on it (else: the nearest stack's).

    ``given`` (or ``$CONFLICTBENCH_DOCTOR_GOLDENS``) names one stack's folder or a root of stack folders; by default
    the shipped ones."""
    given = given or os.environ.get(GOLDENS_VARIABLE) or None
    root = Path(given) if given else GOLDENS_ROOT
    if given and not root.is_dir():
        raise UserError(f"no such goldens folder: {root}")
    if (root / META).is_file():
        goldens = read(root)
        return goldens, goldens.stack_key == key
    keys = sorted(p.name for p in root.iterdir() if (p / META).is_file()) if root.is_dir() else []
    if not keys:
        raise UserError(f"no goldens in {root} (scripts/make_goldens.py makes them)")
    chosen = key if key in keys else nearest(keys, key)
    return read(root / chosen), chosen == key
