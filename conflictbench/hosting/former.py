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
from typing import Any

from .. import core
from ..core.deprecation import REMOVED_IN, deprecated, moved_names

__all__ = ["FORMER_CORE_MODULES", "FORMER_CORE_NAMES", "REMOVED_IN", "deprecated", "install", "moved_names"]

#: ``conflictbench.core``'s modules until 0.2, and their names in this package since 0.3.
FORMER_CORE_MODULES = {"serving": "client", "transport": "transport", "hosting": "hosted", "launch": "launch"}
#: The names those modules lent ``conflictbench.core`` until 0.2 (``from conflictbench.core import HostedPolicy``),
#: each with the module of this package that holds it now.
FORMER_CORE_NAMES = {
    "HostedConfig": "hosted", "HostedPolicy": "hosted", "MODEL_PROCESS_ENV": "hosted",
    "HttpJsonTransport": "transport", "Transport": "transport",
    "PolicyClient": "client", "ServedPolicy": "client", "ServingConfig": "client",
    "ServerProcess": "launch", "free_port": "launch", "model_environment": "launch",
}  # fmt: skip

_core_names = moved_names(
    "conflictbench.core", {name: f"{__package__}.{new}:{name}" for name, new in FORMER_CORE_NAMES.items()}
)


def former_core_attribute(name: str) -> Any:
    """``conflictbench.core.NAME`` for a name that moved to this package (a stand-in module for a former module):
    ``conflictbench.core``'s ``__getattr__`` (PEP 562), set by :func:`install`, whose caller the warning blames."""
    if name.startswith("_"):  # what tools ask of any module (``__path__``, ``__wrapped__``): never a former name
        raise AttributeError(f"module 'conflictbench.core' has no attribute {name!r}")
    if name in FORMER_CORE_MODULES:
        return importlib.import_module(f"conflictbench.core.{name}")
    return _core_names(name, 2)  # past this function


_ABSENT = object()  # a name the moved module did not hold


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

    def __setattr__(self, name: str, value: Any) -> None:
        """A name set here (``mock.patch("conflictbench.core.launch.free_port", ...)``) is set where the code reads it,
        the moved module, so that a test patching the old place still patches what runs; its value there is kept
        for :meth:`__delattr__`."""
        if name.startswith("__"):
            super().__setattr__(name, value)
            return
        deprecated(f"{self.__name__}.{name}", f"set {name} on {self.__moved_to__}")
        new = importlib.import_module(self.__moved_to__)
        self.__dict__.setdefault("__patched__", {}).setdefault(name, getattr(new, name, _ABSENT))
        setattr(new, name, value)

    def __delattr__(self, name: str) -> None:
        """Undoing a patch made here (pytest's ``monkeypatch`` and ``mock.patch`` delete what they set on a module
        that held no such name of its own) gives the moved module its own value back."""
        deprecated(f"{self.__name__}.{name}", f"delete {name} from {self.__moved_to__}")
        new = importlib.import_module(self.__moved_to__)
        original = self.__dict__.get("__patched__", {}).pop(name, _ABSENT)
        if original is _ABSENT:
            delattr(new, name)
        else:
            setattr(new, name, original)

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
    """Put the finder of the former core modules on ``sys.meta_path`` (once), and give ``conflictbench.core`` the
    ``__getattr__`` that finds the former names: set from here, so that core imports nothing of this package."""
    core.__getattr__ = former_core_attribute
    if not any(isinstance(finder, _FormerCoreModules) for finder in sys.meta_path):
        sys.meta_path.append(_FormerCoreModules())
