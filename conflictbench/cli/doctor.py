"""``conflictbench doctor``: is this machine's simulator the reference one? (and, with ``model=``, the model's)"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from conflictbench.cli.args import Parser
from conflictbench.core.plugins import Plugins


def command(argv: Sequence[str], plugins: Plugins) -> int:
    parser = Parser(
        prog="conflictbench doctor",
        description="Replay the golden scripted-expert episodes shipped for this simulator stack, with and without "
        "cameras, and say whether the physics (end-effector paths, success steps) and the rendering (frames of both "
        "cameras) are the reference ones; also the stack: versions, GL, GPU. Exit code 0: all is the reference; 1: "
        "something is not. With model=NAME (and its overrides, e.g. model.checkpoint=DIR): the model's checks too.",
    )
    parser.add_argument("overrides", nargs="*", metavar="model=NAME", help="the model to check, Hydra-style")
    parser.add_argument("--goldens", metavar="DIR", help="the goldens to compare with (one stack's folder, or "
                        "a folder of stacks' folders; also $CONFLICTBENCH_DOCTOR_GOLDENS); default: "
                        "the shipped ones")  # fmt: skip
    parser.add_argument("--perturb", action="append", default=[], metavar="NAME=VALUE", help="a developer's tool: "
                        "change the physics of the replays (e.g. iterations=5, timestep=0.0021, qpos_ulp=1) to see "
                        "what doctor says of a simulator that is not the reference one")  # fmt: skip
    args = parser.parse_args(argv)
    from conflictbench.core import UserError

    stray = [arg for arg in args.overrides if "=" not in arg]
    if stray:
        raise UserError(f"conflictbench doctor: unexpected argument {stray[0]!r} (models are given as model=NAME)")
    from conflictbench.cli.overrides import check_group_overrides
    from conflictbench.cli.published import KEY as DECLARATION
    from conflictbench.doctor.models import model_checks, model_overrides

    # A run's declaration of its checkpoint is no setting: the same command line as the run's may be given here.
    overrides = [arg for arg in args.overrides if arg.partition("=")[0].lstrip("+") != DECLARATION]
    if args.overrides:  # a mistake is said now, not after minutes of replays
        model_overrides(overrides, plugins)
        check_group_overrides(overrides, plugins)  # a model of this project not installed: the command that adds it
    from conflictbench.doctor.checks import print_checks
    from conflictbench.doctor.replaying import parse_perturbations
    from conflictbench.doctor.simulator import simulator_checks

    perturbations = parse_perturbations(args.perturb)
    passed = print_checks(simulator_checks(args.goldens, perturbations, progress=sys.stderr), sys.stdout)
    if args.overrides:
        passed = print_checks(model_checks(overrides, plugins), sys.stdout) and passed
    return 0 if passed else 1
