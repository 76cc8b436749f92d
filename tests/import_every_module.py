"""Import every module of conflictbench as installed (the wheel's two trees: ``conflictbench`` and Hydra's
``hydra_plugins.conflictbench_ray_launcher``), one after another in this process, and say how each went.

    python import_every_module.py [--block NAME,...] [--extras NAME,...] [--strict]

A module passes if it imports, or if it stops at once with a one-line ``ImportError`` naming an extra that
conflictbench declares (``conflictbench[openpi]``): the protocol modules of ``conflictbench.hosting`` need their
extra, and say which. With ``--strict`` (every extra installed) only an import passes. ``--block`` makes those
top-level modules unimportable here (``pytest``: nothing but test code may need it), as if not installed;
``--extras`` gives the declared extras (default: the installed distribution's metadata, which an editable install
freezes at install time). One JSON line per module on stdout; exit 1 if any failed, with one line each on stderr.

Never imported: ``__main__`` modules (importing one runs its command) and :data:`EXEMPT`.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.abc
import importlib.metadata
import json
import pkgutil
import re
import sys

#: Modules of the wheel that no Python with conflictbench imports, and why.
EXEMPT = {
    "conflictbench.policies.subject.train_torch": "run by path in the learned subject's training environment "
    "(its requirements: training-requirements.txt beside it), never imported beside conflictbench",
}
ROOTS = ("conflictbench", "hydra_plugins.conflictbench_ray_launcher")
_EXTRA = re.compile(r"conflictbench\[([A-Za-z0-9_.-]+)\]")


class Blocker(importlib.abc.MetaPathFinder):
    """Makes the named top-level modules (and theirs) unimportable, as if they were not installed."""

    def __init__(self, names: set[str]):
        self.names = names

    def find_spec(self, fullname, path=None, target=None):
        if fullname.partition(".")[0] in self.names:
            raise ModuleNotFoundError(f"No module named {fullname!r} (blocked)", name=fullname)
        return None


def module_names() -> list[str]:
    """Every module under :data:`ROOTS` that exists here, packages before their modules."""
    names: list[str] = []
    for root in ROOTS:
        try:
            package = importlib.import_module(root)
        except ModuleNotFoundError as exc:
            if exc.name is not None and root.startswith(exc.name):  # that tree is not installed (an editable install)
                continue
            raise
        names.append(root)
        found = pkgutil.walk_packages(package.__path__, f"{root}.", onerror=names.append)  # a failed package: listed
        names.extend(info.name for info in found)
    return sorted({name for name in names if name.rpartition(".")[2] != "__main__"})


def outcome(name: str, extras: set[str]) -> dict[str, str]:
    try:
        importlib.import_module(name)
    except ImportError as exc:
        text = str(exc)
        named = _EXTRA.search(text)
        if name in EXEMPT:
            return {"module": name, "outcome": "exempt", "error": f"{type(exc).__name__}: {text}"}
        if named and named[1] in extras and "\n" not in text:
            return {"module": name, "outcome": "extra", "extra": named[1], "error": text}
        return {"module": name, "outcome": "failed", "error": f"{type(exc).__name__}: {text}"}
    except Exception as exc:  # anything else a module raises on import is a fault of the module
        return {"module": name, "outcome": "failed", "error": f"{type(exc).__name__}: {exc}"}
    return {"module": name, "outcome": "ok"}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.partition("\n\n")[0])
    parser.add_argument("--block", default="", help="top-level modules made unimportable, comma-separated")
    parser.add_argument("--extras", default=None, help="the declared extras (default: the installed metadata's)")
    parser.add_argument("--strict", action="store_true", help="every module must import (every extra installed)")
    args = parser.parse_args()
    blocked = {name for name in args.block.split(",") if name}
    for name in list(sys.modules):
        if name.partition(".")[0] in blocked:
            sys.exit(f"{name} was imported before it could be blocked")
    sys.meta_path.insert(0, Blocker(blocked))
    if args.extras is None:
        extras = set(importlib.metadata.metadata("conflictbench").get_all("Provides-Extra") or [])
    else:
        extras = {name for name in args.extras.split(",") if name}
    failed = 0
    for name in module_names():
        said = outcome(name, extras)
        if said["outcome"] == "failed" or (args.strict and said["outcome"] == "extra"):
            failed += 1
            print(f"{name}: {said['error']}", file=sys.stderr)
        print(json.dumps(said), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
