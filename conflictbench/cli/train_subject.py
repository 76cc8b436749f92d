"""``conflictbench train-subject``: the learned subject from scratch, seeded, each stage resumable.

1. demonstrations: the scripted expert on every base task at the training initial states (none of the
   states evaluated), through the normal runner, with noise on what it executes (DART);
2. the frames as a LeRobot dataset (the training environment's LeRobot writes it);
3. training (PyTorch in the training environment); the weights, a ``.npz``, are what the policy reads.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from conflictbench.core import LIBERO_SUITES, UserError
from conflictbench.hosting import model_environment

FIRST_TRAINING_STATE = 5
"""States 0-4 are the evaluation's: never demonstrated."""
INIT_STATES = 50
TRAINING_ENVIRONMENT = "subject"
"""``.venv/models/subject``: Python 3.12 with ``lerobot[dataset]`` (``scripts/setup.sh`` builds it)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):
        raise UserError(f"train-subject: {message}")


def _states(text: str) -> list[int]:
    try:
        if "-" in text:
            first, last = (int(x) for x in text.split("-", 1))
            states = list(range(first, last + 1))
        else:
            states = [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected FIRST-LAST or a comma-separated list, got {text!r}") from None
    if not states:
        raise argparse.ArgumentTypeError(f"no initial states in {text!r}")
    if min(states) < FIRST_TRAINING_STATE or max(states) >= INIT_STATES:
        raise argparse.ArgumentTypeError(
            f"demonstration states must be in {FIRST_TRAINING_STATE}-{INIT_STATES - 1} (0-{FIRST_TRAINING_STATE - 1} "
            f"are evaluated; LIBERO has {INIT_STATES} per task), got {text!r}"
        )
    return states


def _task_ids(text: str) -> list[int]:
    try:
        ids = [int(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list of task ids, got {text!r}") from None
    if not ids or min(ids) < 0 or max(ids) > 9:
        raise argparse.ArgumentTypeError(f"task ids are 0-9, got {text!r}")
    return ids


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog="conflictbench train-subject", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("subject-training"), help="where every stage writes")
    p.add_argument("--init-states", type=_states, default=_states("10-23"), help="demonstration states (10-23)")
    p.add_argument("--libero-suites", nargs="+", default=list(LIBERO_SUITES), choices=LIBERO_SUITES)
    p.add_argument("--task-ids", type=_task_ids, default=None, help="only these tasks of each suite (default: all)")
    p.add_argument("--noise", type=float, default=0.2, help="std of the noise on executed arm actions (0.2)")
    p.add_argument("--workers", type=int, default=2, help="simulator processes recording (2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int, default=30)
    p.add_argument("--minutes", type=float, default=45.0, help="training stops after the epoch that passes this")
    p.add_argument("--threads", type=int, default=2, help="torch threads for training (2)")
    p.add_argument("--python", type=Path, default=None, help="the training environment's python")
    return p


def _say(message: str) -> None:
    print(f"conflictbench: {message}", file=sys.stderr, flush=True)


PROBE = """
import importlib.util, sys
missing = [name for name in ("torch", "lerobot", "datasets") if importlib.util.find_spec(name) is None]
if missing:
    sys.exit(f"ModuleNotFoundError: No module named {missing[0]!r}")
"""


def _training_python(given: Path | None) -> Path:
    python = given or model_environment(TRAINING_ENVIRONMENT) / "bin" / "python"
    if not Path(python).exists():
        raise UserError(
            f"no training environment at {python}: `scripts/setup.sh` builds it (Python 3.12 with LeRobot's "
            "dataset stack and PyTorch), or name another with --python"
        )
    # Found, not imported: importing them takes about 25 s here, and the training step imports them anyway.
    probe = subprocess.run([str(python), "-c", PROBE], capture_output=True, text=True)
    if probe.returncode != 0:
        why = (probe.stderr.strip().splitlines() or [f"exit code {probe.returncode}"])[-1]
        raise UserError(f"{python} cannot train the subject ({why}): `scripts/setup.sh` builds the environment")
    return Path(python)


def _in_training_environment(python: Path, *args: str) -> None:
    script = Path(__file__).resolve().parent.parent / "policies" / "subject" / "train_torch.py"
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    env.pop("PYTHONPATH", None)  # the simulator's packages must not leak into the other interpreter
    done = subprocess.run([str(python), str(script), *args], env=env)
    if done.returncode != 0:
        raise UserError(f"train-subject: the training environment's step `{args[0]}` failed (exit {done.returncode})")


def command(argv: list[str], plugins) -> int:
    from conflictbench.policies.subject.prepare import write_prepared
    from conflictbench.sim.demonstrations import record_demonstrations
    from conflictbench.tasks.libero.base_tasks import all_base_tasks

    args = parser().parse_args(argv)
    if args.workers < 1 or args.threads < 1 or args.epochs < 1 or args.noise < 0:
        raise UserError("train-subject: --workers, --threads and --epochs must be >= 1 and --noise >= 0")
    python = _training_python(args.python)  # before an hour of recording, not after
    out: Path = args.out
    timings: dict[str, float] = {}

    started = time.monotonic()
    _say(f"1/3 demonstrations: the expert on {len(args.libero_suites)} LIBERO suite(s) x states {args.init_states}")
    count = record_demonstrations(
        out / "demonstrations",
        init_states=args.init_states,
        noise=args.noise,
        workers=args.workers,
        libero_suites=tuple(args.libero_suites),
        task_ids=tuple(args.task_ids) if args.task_ids else None,
    )
    if count == 0:
        raise UserError("train-subject: the expert succeeded in no episode; nothing to learn from")
    timings["demonstrations_s"] = time.monotonic() - started

    started = time.monotonic()
    _say(f"2/3 dataset: {count} demonstrations -> LeRobot dataset {out / 'dataset'}")
    instructions = [t.language for t in all_base_tasks(tuple(LIBERO_SUITES))]
    prepared = write_prepared(out / "demonstrations" / "episodes", out / "prepared", instructions)
    dataset = out / "dataset"
    if dataset.exists():
        import shutil

        shutil.rmtree(dataset)  # LeRobot writes a dataset once; it is made again from the demonstrations
    # One process writes the dataset and trains (it says when training starts): torch and LeRobot load once.
    weights = out / "subject.npz"
    _in_training_environment(
        python, "train", "--prepared", str(prepared), "--root", str(dataset), "--out", str(weights),
        "--seed", str(args.seed), "--epochs", str(args.epochs), "--minutes", str(args.minutes),
        "--threads", str(args.threads), "--report", str(out / "training-run.json"),
    )  # fmt: skip
    run = json.loads((out / "training-run.json").read_text())
    timings["dataset_s"] = run.pop("dataset_s")  # writing it, in the training environment
    timings["training_s"] = time.monotonic() - started - timings["dataset_s"]
    (out / "training.json").write_text(
        json.dumps(
            {"demonstrations": count, **{k: round(v, 1) for k, v in timings.items()}, **vars_of(args), "run": run},
            indent=2,
        )
        + "\n",
        encoding="utf-8",
    )
    minutes = sum(timings.values()) / 60
    _say(f"done in {minutes:.1f} min: {weights}; play it with `conflictbench model=subject model.weights={weights}`")
    return 0


def vars_of(args: argparse.Namespace) -> dict:
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
