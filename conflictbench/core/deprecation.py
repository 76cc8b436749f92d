"""Names kept at a former place for one version: each use warns (``DeprecationWarning``) naming the new place.

Part of the contract so that a plugin can keep its own moved names the same way (``__getattr__ =
moved_names(__name__, {"Old": "package.module:New"})``); imports nothing of conflictbench.
"""

from __future__ import annotations

import importlib
import warnings
from collections.abc import Callable, Mapping
from typing import Any

#: The version in which the names deprecated in 0.3 go (``CHANGELOG.md``).
REMOVED_IN = "0.4.0"


def deprecated(what: str, instead: str, stacklevel: int = 1) -> None:
    """Warn that ``what`` is deprecated, saying ``instead``; ``stacklevel`` 1 blames the caller's caller."""
    warnings.warn(
        f"{what} is deprecated and goes in conflictbench {REMOVED_IN}: {instead}",
        DeprecationWarning,
        stacklevel=stacklevel + 2,
    )


def moved_names(module: str, names: Mapping[str, str]) -> Callable[..., Any]:
    """A module ``__getattr__`` (PEP 562) for names that moved: ``names`` maps each old name to its new place,
    ``"package.module:NAME"``. Reading one warns, naming that place, and gives the object there."""

    def __getattr__(name: str, stacklevel: int = 1) -> Any:  # stacklevel 1: blame the code that read the name
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        where, _, attribute = names[name].partition(":")
        deprecated(f"{module}.{name}", f"import {attribute} from {where}", stacklevel)
        return getattr(importlib.import_module(where), attribute)

    return __getattr__
