"""The model stack a model runs on, as an episode's identity counts it: each installed distribution's version and the
kind of device.

Read from the distributions' metadata on disk, without importing them, so a run knows it before it plans (a model
server takes minutes to start): for a local checkpoint a short probe in the model environment's interpreter prints
it (``conflictbench.hosting.hosted``; it also decides ``--device auto`` as the server would), and a server of
``conflictbench-serve`` says the same in its metadata (``model_stack``), which the run checks against it, and for a
run given ``model.server=``. Every
distribution counts, not a list of known ones: a model's numbers can move with torch, its CUDA kernels,
transformers or the model's own library alike. The installers (pip, setuptools, wheel, uv) do not run a model.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from importlib import metadata
from pathlib import Path

INSTALLERS = frozenset({"pip", "setuptools", "wheel", "uv"})


def canonical_name(name: str) -> str:
    """A distribution's name as package indexes compare them (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def installed_versions(paths: Iterable[str | Path] | None = None) -> dict[str, str]:
    """``{name: version}`` of the distributions on ``paths`` (default: this interpreter's ``sys.path``), the first of
    a name on the path winning as it does on import, installers left out, by name."""
    found = metadata.distributions() if paths is None else metadata.distributions(path=[str(p) for p in paths])
    versions: dict[str, str] = {}
    for dist in found:
        name = dist.metadata["Name"]
        if name and canonical_name(name) not in INSTALLERS:
            versions.setdefault(canonical_name(name), dist.version)
    return dict(sorted(versions.items()))


def model_stack(device: str, versions: Mapping[str, str]) -> dict[str, object]:
    """What an episode's identity counts of the stack: the device kind (``cuda:1`` runs as ``cuda:0`` does) and
    every distribution's version."""
    return {"device": device.partition(":")[0], "packages": dict(sorted(versions.items()))}
