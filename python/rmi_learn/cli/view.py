"""``rmi view``: an interactive 3D view of trials without ParaView, as a rerun recording.

    rmi simulate --config trial.json --out out/one --vtk-every 20
    rmi view --rrd out/one.rrd out/one [out/two ...]
    rerun out/one.rrd

Needs the optional ``rerun-sdk`` package (``pip install rerun-sdk``); without it the
command ends with one line saying so. See :mod:`rmi_learn.sim.rerun_view`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rmi_learn.option_types import count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi view``."""
    parser.add_argument(
        "runs",
        nargs="+",
        type=Path,
        metavar="RUN",
        help="`rmi simulate` output directories (their VTK frames give the 3D view)",
    )
    parser.add_argument(
        "--rrd",
        required=True,
        type=Path,
        metavar="FILE",
        help="the rerun recording to write (missing folders are made)",
    )
    parser.add_argument(
        "--every", type=count(1), default=1, metavar="K", help="include every K-th VTK frame"
    )


def run(args: argparse.Namespace) -> int:
    """Write the recording; 0 on success, 1 without rerun-sdk, 2 for a missing run or a
    recording that cannot be written (nothing is left of it then)."""
    from rmi_learn.sim.rerun_view import write_recording

    summary = write_recording(args.runs, args.rrd, every=args.every)
    print(
        f"wrote {summary['path']}: {summary['runs']} run(s), {summary['frames']} frame(s), "
        f"{summary['records']} records; open it with `rerun {summary['path']}`"
    )
    return 0
