"""The ``rmi`` command line: one entry point, one module per subcommand.

Each subcommand module (``rmi_learn.cli.<name>``) holds its options (``add_arguments``) and a
``run(args) -> int`` that calls the library function of its stage with typed arguments. The
modules import nothing heavy at the top, so ``rmi --help`` stays fast and a missing optional
dependency only affects the command that needs it.
"""

from __future__ import annotations

import argparse
import sys
from types import ModuleType

from rmi_learn.cli import (
    analyze,
    closed_loop,
    control_bench,
    dataset,
    distill_policy,
    eval_wm,
    pipeline,
    rank,
    report,
    simulate,
    sweep,
    train_policy,
    train_wm,
    view,
)
from rmi_learn.cli.helpformat import DefaultsHelpFormatter
from rmi_learn.cli.version import VersionAction

#: The packages of the ``learn`` extra: a command that needs one of them and finds it missing
#: says how to install it (status 1, as for other missing optional backends).
LEARN_EXTRA = frozenset({"torch", "safetensors"})
#: How to install them.
LEARN_INSTALL = "pip install 'rmi[learn]'"

#: command name -> (module, one-line help)
COMMANDS: dict[str, tuple[ModuleType, str]] = {
    "simulate": (simulate, "run one grasp-lift-squeeze trial, write Parquet and VTK"),
    "sweep": (sweep, "run a grid of trials (resumable, local or Ray)"),
    "dataset": (dataset, "resample runs to 20 ms and build learning windows"),
    "analyze": (analyze, "physical analysis of a run grid: figures and numbers"),
    "train-wm": (train_wm, "train a world model"),
    "eval-wm": (eval_wm, "evaluate world models, write the forecast-error tables"),
    "train-policy": (train_policy, "train a goal-conditioned UNet policy"),
    "distill-policy": (distill_policy, "distil a policy into a 1-2 step real-time student"),
    "rank": (rank, "rank policy samples with a world model, write the ranking tables"),
    "closed-loop": (closed_loop, "execute ranked actions in the simulator"),
    "control-bench": (control_bench, "goal-reaching benchmark of the controllers, executed"),
    "pipeline": (pipeline, "run every stage from sweep to report"),
    "report": (report, "write report.md and report.html"),
    "view": (view, "write a rerun recording of trials: particles, pads, forces, water"),
}


def build_parser() -> argparse.ArgumentParser:
    """The ``rmi`` parser with one subparser per command of :data:`COMMANDS`."""
    parser = argparse.ArgumentParser(prog="rmi", description="Robotic Multiphase Interaction")
    parser.add_argument("--version", action=VersionAction)
    # Not dest="command": `rmi closed-loop --command` would overwrite the command's name.
    sub = parser.add_subparsers(dest="rmi_command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(
            name, help=help_text, description=help_text, formatter_class=DefaultsHelpFormatter
        )
        module.add_arguments(p)
    return parser


def _with_options_file(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``argv`` with the options of the command's ``--config`` file in front of the
    command's own, for the commands whose module sets ``OPTIONS_FILE`` (see
    :mod:`rmi_learn.cli.options_file`)."""
    from rmi_learn.cli import options_file

    if not argv or argv[0] not in COMMANDS:
        return argv
    if not getattr(COMMANDS[argv[0]][0], "OPTIONS_FILE", False):
        return argv
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return [argv[0], *options_file.expand(sub.choices[argv[0]], argv[1:])]


def main(argv: list[str] | None = None) -> int:
    """Run one ``rmi`` command. Outputs are written atomically, so what finished is kept
    after Ctrl-C (status 130), and the resumable commands (sweep, train-*, closed-loop,
    pipeline) pick up from there when rerun. Input errors end with one line and status 2
    (see :mod:`rmi_learn.errors`)."""
    from rmi_learn.errors import InputError, report

    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        argv = _with_options_file(parser, argv)
    except InputError as exc:
        status = report(argv[0], exc)
        assert status is not None
        return status
    args = parser.parse_args(argv)
    module = COMMANDS[args.rmi_command][0]
    try:
        return int(module.run(args) or 0)
    except ModuleNotFoundError as exc:
        if (exc.name or "").partition(".")[0] not in LEARN_EXTRA:
            raise
        print(
            f"rmi {args.rmi_command}: needs {exc.name}, which is not installed: {LEARN_INSTALL}",
            file=sys.stderr,
        )
        return 1
    except (Exception, KeyboardInterrupt) as exc:
        status = report(args.rmi_command, exc)
        if status is None:
            raise
        return status


if __name__ == "__main__":
    sys.exit(main())
