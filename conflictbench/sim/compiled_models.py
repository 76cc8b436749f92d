"""Compile each LIBERO scene once per process (and, where asked, once per machine) instead of at every reset.

robosuite builds a new simulator from the scene's XML at env construction and at every reset (a hard
reset, which is what native LIBERO clients do, so we keep it). Compiling a LIBERO scene takes ~5 s of
CPU here, most of an episode's set-up, and the XML is the same every time for one task. A compiled
``MjModel`` is plain data: a copy of it, or one loaded from MuJoCo's own binary format (MJB), saves back
to exactly the bytes a fresh compile saves (``tests/test_compiled_models.py``), and a fresh ``MjData`` on
it steps bit-identically; the camera-physics tests compare against native clients that compile every time.

- In a process, the last scene compiled is kept (one model: a LIBERO scene with its textures is ~250 MB),
  so a worker playing several episodes of a task compiles it once.
- ``CONFLICTBENCH_MODEL_CACHE=DIR`` also keeps each scene's MJB in ``DIR`` (~250 MB a scene, 40 base
  tasks), so new processes load instead of compiling; the tests set it (they start many short runs).
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import tempfile
from pathlib import Path

log = logging.getLogger(__name__)

CACHE_DIR_VARIABLE = "CONFLICTBENCH_MODEL_CACHE"
_FILE_ATTRIBUTE = re.compile(r'\bfile="([^"]+)"')
_last: tuple[str, object] | None = None  # (key, pristine MjModel) of the last scene compiled here


def scene_key(xml: str) -> str:
    """What decides a compiled model: MuJoCo's version, the XML, and the files it names (size, mtime)."""
    import mujoco

    digest = hashlib.sha256(f"mujoco {mujoco.__version__}\n".encode())
    digest.update(xml.encode())
    for name in sorted(set(_FILE_ATTRIBUTE.findall(xml))):
        try:
            stat = os.stat(name)
            digest.update(f"\n{name} {stat.st_size} {stat.st_mtime_ns}".encode())
        except OSError:
            digest.update(f"\n{name} missing".encode())  # the compile will say so itself
    return digest.hexdigest()


def compiled_model(xml: str):
    """A fresh ``mujoco.MjModel`` of ``xml``, compiled at most once per process (and per cache directory)."""
    import copy

    import mujoco

    global _last
    key = scene_key(xml)
    if _last is not None and _last[0] == key:
        return copy.copy(_last[1])
    model = _load(key)
    if model is None:
        model = mujoco.MjModel.from_xml_string(xml)
        _store(key, model)
    _last = (key, model)
    return copy.copy(model)


def _cache_file(key: str) -> Path | None:
    directory = os.environ.get(CACHE_DIR_VARIABLE, "").strip()
    return Path(directory) / f"{key}.mjb" if directory else None


def _load(key: str):
    import mujoco

    path = _cache_file(key)
    if path is None or not path.is_file():
        return None
    try:
        return mujoco.MjModel.from_binary_path(str(path))
    except Exception as exc:  # a truncated or foreign file: compile instead, and write it again
        log.warning("compiled model %s unreadable (%s); compiling the scene", path, exc)
        return None


def _store(key: str, model) -> None:
    import mujoco
    import numpy as np

    path = _cache_file(key)
    if path is None:
        return
    part = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        buffer = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
        mujoco.mj_saveModel(model, None, buffer)
        # Whole or not at all: another process may be reading or writing the same scene.
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".part", delete=False) as part:
            part.write(buffer.tobytes())
        os.replace(part.name, path)
    except OSError as exc:
        log.warning("cannot keep the compiled model in %s (%s)", path.parent, exc)
        if part is not None:
            Path(part.name).unlink(missing_ok=True)


def install() -> None:
    """Make robosuite build every simulator from :func:`compiled_model` (in this process)."""
    from robosuite.utils import binding_utils

    sim_class = binding_utils.MjSim
    if getattr(sim_class, "_conflictbench_compiled_models", False):
        return

    def from_xml_string(cls, xml):
        return cls(compiled_model(xml))

    sim_class.from_xml_string = classmethod(from_xml_string)
    sim_class._conflictbench_compiled_models = True
