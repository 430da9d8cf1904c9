"""The ``rmi`` command line: one entry point, one module per subcommand.

Each subcommand lives in ``rmi_learn.commands.<name>`` with ``add_arguments(parser)`` and
``run(args) -> int``; modules are imported only when their command runs, so ``rmi --help``
stays fast and a missing optional dependency only affects the command that needs it.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys

#: command name -> (module under rmi_learn.commands, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {}


def _register(name: str, module: str, help_text: str) -> None:
    COMMANDS[name] = (module, help_text)


_register("simulate", "simulate", "run one grasp-lift-squeeze trial, write Parquet and VTK")
_register("sweep", "sweep", "run a grid of trials (resumable, local or Ray)")
_register("dataset", "dataset", "resample runs to 20 ms and build learning windows")
_register("analyze", "analyze", "physical analysis of a run grid: figures and numbers")
_register("train-wm", "train_wm", "train a world model")
_register("eval-wm", "eval_wm", "evaluate world models, write Tables II-IV")
_register("train-policy", "train_policy", "train a goal-conditioned UNet policy")
_register("rank", "rank", "rank policy samples with the world model, write Tables III, V, S1")
_register("closed-loop", "closed_loop", "execute ranked actions in the simulator")
_register("pipeline", "pipeline", "run every stage from sweep to report")
_register("report", "report", "write report.md and report.html")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rmi", description="Robotic Multiphase Interaction")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        try:
            mod = importlib.import_module(f"rmi_learn.commands.{module}")
        except ModuleNotFoundError as exc:
            if exc.name != f"rmi_learn.commands.{module}":
                raise
            # Not written yet: the command exists in the help but says so when run.
            p.set_defaults(_missing=True)
            continue
        mod.add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if getattr(args, "_missing", False):
        print(f"rmi {args.command}: not available in this build", file=sys.stderr)
        return 2
    mod = importlib.import_module(f"rmi_learn.commands.{args._module}")
    try:
        return int(mod.run(args) or 0)
    except KeyboardInterrupt:
        # Outputs are written atomically, so what finished is kept; the resumable commands
        # (sweep, train-*, closed-loop, pipeline) pick up from there when rerun.
        print(f"rmi {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if not _is_input_error(exc):
            raise
        print(f"rmi {args.command}: {exc}", file=sys.stderr)
        return 2


def _is_input_error(exc: Exception) -> bool:
    """Whether ``exc`` says the user's input is wrong (a path that is missing or unreadable,
    a file that is not JSON, a damaged run file, a config value out of range, or an
    :class:`~rmi_learn.commands.InputError` a command raised for what it caught) rather than
    that the code is: such errors end the command with their message and exit status 2,
    where a bug keeps its traceback. This is the one place that turns input errors into the
    message and the status."""
    import rmi_sph
    from rmi_learn.commands import InputError
    from rmi_learn.runs import RunFileError

    paths = (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError)
    inputs = (PermissionError, json.JSONDecodeError, RunFileError, rmi_sph.ConfigError, InputError)
    return isinstance(exc, (*paths, *inputs))


if __name__ == "__main__":
    sys.exit(main())
