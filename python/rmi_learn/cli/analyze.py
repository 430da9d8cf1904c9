"""``rmi analyze``: physical analysis of a run grid (paper Sec. VI.A, Figs. 4-6).

Reads a sweep directory (``index.parquet`` and ``runs/``) or a bare runs tree and writes to
``--out``: ``fig4_single_run.png`` (forces in N and retained water in g of one run against
time, phases shaded), ``fig5_water_per_phase.png`` (water removed per controller phase, g),
``fig6_lift_success.png`` (lift success over porosity x holding force per sponge size),
``fig_squeeze_association.png`` (squeeze-phase removal against squeeze force within matched
groups) and ``analysis.json`` (every number, run counts and the paper's stated numbers).
See :mod:`rmi_learn.analysis.physical`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rmi_learn.option_types import count, seed


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """CLI options of ``rmi analyze``."""
    parser.add_argument(
        "--runs",
        required=True,
        type=Path,
        help="sweep output directory (index.parquet + runs/) or a bare runs tree",
    )
    parser.add_argument("--out", required=True, type=Path, help="directory for figures and JSON")
    parser.add_argument(
        "--run-id",
        default=None,
        help="run drawn in the single-run figure (forces and retained water against time), "
        "e.g. size_cm=10/porosity=0.6/F_hold=110/F_squeeze=200/seed=0 "
        "(default: the completed run closest to the grid's median parameters)",
    )
    parser.add_argument(
        "--bootstrap",
        type=count(1),
        default=2000,
        help="cluster bootstrap resamples",
    )
    parser.add_argument("--seed", type=seed, default=0, help="bootstrap random seed")


def run(args: argparse.Namespace) -> int:
    """Write the figures and ``analysis.json``; print a short summary. Returns 0, or 2 when
    the input cannot be analysed."""
    from rmi_learn.analysis.physical import analyze, summary_lines

    # An input that cannot be analysed raises AnalysisError, an input error (status 2).
    result = analyze(args.runs, args.out, args.run_id, n_boot=args.bootstrap, seed=args.seed)
    for line in summary_lines(result):
        print(line)
    print(f"wrote {len(result['files'])} files to {args.out}")
    return 0
