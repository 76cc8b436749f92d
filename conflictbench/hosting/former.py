"""Names kept at their former places for one version: each use warns (``DeprecationWarning``) naming the new place,
and they go in conflictbench 0.4.0 (``CHANGELOG.md``).

- ``conflictbench.core.serving``, ``.transport``, ``.hosting`` and ``.launch``, the modules that moved to this
  package in 0.3 (``client``, ``transport``, ``hosted``, ``launch``): importing one gives a stand-in whose every
  name read warns and is the moved module's own object (:class:`_FormerCoreModules`, on ``sys.meta_path`` once
  :mod:`conflictbench.hosting` is imported, which ``import conflictbench`` does first);
- ``conflictbench.core.HostedPolicy`` and the other names those modules held: ``conflictbench.core``'s
  ``__getattr__`` (PEP 562) asks :func:`former_core_attribute`;
- a plugin's own moved names (the model plugins' ``transport`` modules): :func:`moved_names` makes their
  ``__getattr__``.

Python shows a ``DeprecationWarning`` where code run as ``__main__`` triggers it, and pytest shows them all; ``-W
error::DeprecationWarning`` makes each an error, the way to find every old name a plugin still uses.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import types
import warnings
from collections.abc import Callable, Mapping
from typing import Any

#: The version in which the deprecated names go.
REMOVED_IN = "0.4.0"
#: ``conflictbench.core``'s modules until 0.2, and their names in this package since 0.3.
FORMER_CORE_MODULES = {"serving": "client", "transport": "transport", "hosting": "hosted", "launch": "launch"}
#: The names those modules lent ``conflictbench.core`` until 0.2 (``from conflictbench.core import HostedPolicy``).
FORMER_CORE_NAMES = (
    "HostedConfig", "HostedPolicy", "HttpJsonTransport", "MODEL_PROCESS_ENV", "PolicyClient", "ServedPolicy",
    "ServerProcess", "ServingConfig", "Transport", "free_port", "model_environment",
)  # fmt: skip


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


_core_names = moved_names("conflictbench.core", {name: f"conflictbench.hosting:{name}" for name in FORMER_CORE_NAMES})


def former_core_attribute(name: str) -> Any:
    """``conflictbench.core.NAME`` for a name that moved to this package (a stand-in module for a former module);
    called by ``conflictbench.core.__getattr__``, whose caller the warning blames."""
    if name in FORMER_CORE_MODULES:
        return importlib.import_module(f"conflictbench.core.{name}")
    return _core_names(name, 3)  # past this function and core's __getattr__


class _MovedModule(types.ModuleType):
    """A former module at its old place: each name read from it warns and is the new module's."""

    def __init__(self, name: str, new: str):
        super().__init__(name, f"Deprecated (goes in conflictbench {REMOVED_IN}): moved to {new}.")
        self.__moved_to__ = new

    def __getattr__(self, name: str) -> Any:
        new = importlib.import_module(self.__moved_to__)
        if name == "__all__":  # a star import takes what the module had, each name through here
            return [n for n in vars(new) if not n.startswith("_")]
        if name.startswith("__"):  # what the import system and tools ask of any module: not a name it held
            raise AttributeError(name)
        deprecated(f"{self.__name__}.{name}", f"import {name} from {self.__moved_to__}")
        return getattr(new, name)

    def __dir__(self) -> list[str]:
        return dir(importlib.import_module(self.__moved_to__))


class _FormerCoreModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``conflictbench.core.serving`` and the other former core modules as :class:`_MovedModule` stand-ins."""

    PREFIX = "conflictbench.core."

    def find_spec(self, fullname, path=None, target=None):
        if fullname.startswith(self.PREFIX) and fullname[len(self.PREFIX) :] in FORMER_CORE_MODULES:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        new = FORMER_CORE_MODULES[spec.name[len(self.PREFIX) :]]
        return _MovedModule(spec.name, f"{__package__}.{new}")

    def exec_module(self, module) -> None:
        """Nothing to run: the stand-in reads every name from the moved module."""


def install() -> None:
    """Put the finder of the former core modules on ``sys.meta_path`` (once)."""
    if not any(isinstance(finder, _FormerCoreModules) for finder in sys.meta_path):
        sys.meta_path.append(_FormerCoreModules())
