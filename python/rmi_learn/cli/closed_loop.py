"""``rmi closed-loop``: execute ranked action chunks in the simulator and report the real
terminal water error (see :mod:`rmi_learn.closed_loop`).

``rmi closed-loop --runs SWEEP_DIR --chunks RANK_DIR --out DIR [--max-windows 4]
[--threads N]``

The chunks are force setpoints, executed through the engine's force loop.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.option_types import count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi closed-loop``."""
    parser.add_argument(
        "--runs", required=True, type=Path, metavar="SWEEP_DIR", help="sweep output (index.parquet)"
    )
    parser.add_argument(
        "--chunks",
        required=True,
        type=Path,
        metavar="RANK_DIR",
        help="`rmi rank` output with chunks_diffusion.npz and/or chunks_flow.npz",
    )
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="output directory")
    parser.add_argument(
        "--max-windows",
        type=count(0),
        default=4,
        metavar="N",
        help="windows per sponge size, evenly spaced (0: all)",
    )
    add_threads(parser, "the engine (with several runs, that many runs at a time on one each)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Execute the windows and write the tables; 0 on success, 2 for unusable inputs, 1 when
    another closed-loop writes ``--out``."""
    from rmi_learn.closed_loop import run_closed_loop

    # Inputs that cannot be executed raise ClosedLoopError, an input error (status 2).
    summary = run_closed_loop(
        args.runs,
        args.chunks,
        args.out,
        max_windows=args.max_windows,
        threads=threads_of(args.threads),
        progress=not args.no_progress,
        log=lambda msg: print(msg, file=sys.stderr),
    )
    brief = {
        "out": str(args.out),
        "windows": summary["windows_total"],
        "executed_now": summary["windows_executed_now"],
        "wall_s_per_window": summary["wall_s_per_window"],
        "real_error_g": {
            size: {
                "original": e["original"]["real_g"],
                **{
                    f"{obj}_{k}": e[obj][f"{k}_real_g"]
                    for obj in ("diffusion", "flow")
                    if obj in e
                    for k in ("first", "selected")
                },
            }
            for size, e in summary["sizes"].items()
        },
    }
    print(json.dumps(brief, indent=2))
    return 0
