"""``rmi pipeline``: every stage from the run grid to the report, resumable.

    rmi pipeline --preset quick --out results/quick
    rmi pipeline --preset paper --out results/paper  # 594 runs: docs/benchmarks.md
    rmi pipeline --config my_pipeline.json --out DIR [--only rank closed-loop report]

A finished stage is skipped on the next call; an interrupted one continues (see
:mod:`rmi_learn.pipeline`). ``OUT/stages/<stage>.json`` records each stage's wall time and
the ``rmi`` command lines that reproduce it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.errors import InputError
from rmi_learn.pipeline import PRESETS, PipelineError, load_preset, run_pipeline


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi pipeline``."""
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--preset", choices=PRESETS, help="a built-in pipeline")
    src.add_argument("--config", type=Path, metavar="FILE", help="a pipeline JSON file")
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory")
    # The sweep stage runs the preset's workers x threads_per_run; the training stages run this
    # many trainings at a time on one thread each; every other stage runs its calls one after
    # another with this many threads.
    add_threads(
        parser,
        "each stage after the sweep (engine and torch; the trainings run that many at a time, "
        "one thread each)",
    )
    parser.add_argument(
        "--only", nargs="+", metavar="STAGE", help="run just these stages (default: every one)"
    )
    parser.add_argument(
        "--redo",
        nargs="+",
        metavar="STAGE",
        help="forget these stages' markers, so they run again (default: none)",
    )


def run(args: argparse.Namespace) -> int:
    """Run the pipeline; 0 when every stage finished, 1 when one failed, 2 on bad input."""
    try:
        cfg = load_preset(preset=args.preset) if args.preset else load_preset(path=args.config)
    except (OSError, ValueError) as exc:
        raise InputError(exc) from exc
    threads = threads_of(args.threads)
    try:
        run_pipeline(cfg, args.out, threads=threads, only=args.only, redo=args.redo)
    except ValueError as exc:
        raise InputError(exc) from exc
    except PipelineError as exc:
        print(f"rmi pipeline: {exc}", file=sys.stderr)
        print("run the same command again to continue from this stage", file=sys.stderr)
        return 1
    return 0
