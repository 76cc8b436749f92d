"""The ``conflictbench`` command: one module of this package per verb.

    conflictbench [hydra overrides]   run.py      compose and play a run (``-m`` for sweeps)
    conflictbench list                listing.py  policies, metrics, families, levels, prompts, presets
    conflictbench reproduce ...       reproduce.py  a checkpoint's LIBERO success beside its authors' published figure
    conflictbench report DIR          report.py   tables from an episode store, running nothing
    conflictbench compare DIR A B     compare.py  paired differences between two models, settings or prompts
    conflictbench view DIR            view.py     a static HTML site of the store's pairs, videos by replay
    conflictbench merge OUT SHARD...  merge.py    one store from stores written on different machines
    conflictbench prune DIR           prune.py    the superseded episodes, listed or removed
    conflictbench store check DIR     store.py    read every episode file, name the damaged ones
    conflictbench suite ...           suite.py    validate, inspect, sample, export or rebuild the conflict suite
    conflictbench train-subject       train_subject.py   the learned default policy, trained from scratch
    conflictbench doctor              doctor.py   is this machine's simulator the reference one (golden replays)
    conflictbench new-plugin NAME     new_plugin.py  a served model plugin, both halves, from a template

Each verb's module has ``command(argv, plugins) -> int``; a new verb is a new module named in ``VERBS``.
No module of the package imports this one, and none is named after a builtin: importing
``conflictbench.cli.X`` binds ``X`` in this module's namespace. A mistake of the user's prints one
line and exits with code 2 (so does a plugin that registers something invalid or implements a hook
that does not exist); a simulator that cannot run here prints what to install, and a policy
server that cannot be reached is named by its URL; both exit with code 3. Ctrl-C, SIGTERM and SIGHUP
end a run cleanly (every finished episode stored, a started model server stopped), exit code 130.
"""

from __future__ import annotations

import importlib
import signal
import sys
import threading
from collections.abc import Sequence

from conflictbench.core import UserError
from conflictbench.core.errors import ONE_LINE_ERRORS

VERBS = {
    "list": "listing",
    "report": "report",
    "compare": "compare",
    "reproduce": "reproduce",
    "suite": "suite",
    "view": "view",
    "merge": "merge",
    "prune": "prune",
    "store": "store",
    "train-subject": "train_subject",
    "doctor": "doctor",
    "new-plugin": "new_plugin",
}  # verb -> module; anything else is a run
USAGE = """usage: conflictbench [OVERRIDE ...]        play a run, e.g. model=noop suite=physical prompt=p1
       conflictbench -m [OVERRIDE ...]     sweep, e.g. -m model=noop,random prompt=p0,p1
       conflictbench list                  what can be chosen, and which package provides it
       conflictbench report DIR            tables from the episode store in DIR
       conflictbench compare DIR A B       is the difference real? A, B: models (pi0, subject@p1), paired
       conflictbench reproduce model=M model.checkpoint=DIR model.published=ENTRY [--quick]
                                           does the checkpoint score what its authors published? (LIBERO)
       conflictbench view DIR              a web page per pair (videos, paths, measures): DIR/view/index.html
       conflictbench merge OUT SHARD...    one store from stores written on different machines
       conflictbench prune DIR [--delete]  the episodes stored again under a newer identity, listed or removed
       conflictbench store check DIR [--quarantine]   read every episode file; name (or set aside) damaged ones
       conflictbench suite validate|stats|sample|export|build ...   the conflict suite (see: suite --help)
       conflictbench train-subject [--out DIR]   train the learned default policy from scratch (--help)
       conflictbench doctor [model=NAME ...]     is this machine's simulator the reference one? (--help)
       conflictbench new-plugin NAME --protocol openpi|zeromq|rest   a served model plugin to fill in (--help)
       conflictbench --disable-plugins A,B ...   leave these installed plugins out (not imported); also
                                           CONFLICTBENCH_DISABLE_PLUGINS=A,B
       conflictbench --config-help         the configuration, its groups and their options
       conflictbench --hydra-help          Hydra's own options
"""


def _interrupted(signum: int, frame: object) -> None:
    raise KeyboardInterrupt  # SIGTERM (a batch scheduler's time limit, `kill`) and SIGHUP end a run as Ctrl-C does


def _take_disabled_plugins(argv: list[str]) -> list[str]:
    """Remove ``--disable-plugins A,B`` (anywhere, any number of times) and add the names to
    ``CONFLICTBENCH_DISABLE_PLUGINS``: read before any plugin loads, and inherited by every process the run
    starts (a sweep's jobs, a launcher's workers)."""
    import os

    from conflictbench import DISABLE_PLUGINS_VARIABLE

    names, rest, remaining = [], [], iter(argv)
    for arg in remaining:
        if arg == "--disable-plugins":
            value = next(remaining, None)
            if value is None or value.startswith("-") or "=" in value:
                raise UserError("--disable-plugins needs the plugins' names, e.g. --disable-plugins demo,other")
            names.append(value)
        elif arg.startswith("--disable-plugins="):
            names.append(arg.split("=", 1)[1])
        else:
            rest.append(arg)
    if names:
        earlier = os.environ.get(DISABLE_PLUGINS_VARIABLE, "")
        os.environ[DISABLE_PLUGINS_VARIABLE] = ",".join(n for n in (earlier, *names) if n)
    return rest


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, _interrupted)
    try:
        if argv[:1] in (["-h"], ["--help"], ["help"]):
            print(USAGE, end="")
            return 0
        import conflictbench

        from .overrides import check_verb

        argv = _take_disabled_plugins(argv)
        check_verb(argv, list(VERBS))  # before the plugins load: a typo should not wait on them
        plugins = conflictbench.plugins()
        module, rest = (VERBS[argv[0]], argv[1:]) if argv[:1] and argv[0] in VERBS else ("run", argv)
        return importlib.import_module(f"{__name__}.{module}").command(rest, plugins)
    except ONE_LINE_ERRORS as exc:
        print(f"conflictbench: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except BrokenPipeError:  # output piped into `head` and the like
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except KeyboardInterrupt:
        print(
            "\nconflictbench: interrupted; every finished episode is stored, and the same command resumes the run",
            file=sys.stderr,
        )
        return 130
