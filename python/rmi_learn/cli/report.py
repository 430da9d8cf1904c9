"""``rmi report``: write ``report.md`` and ``report.html`` for a pipeline directory.

    rmi report --out results/quick [--validation DIR]

Reads what the pipeline stages wrote under ``--out`` and writes ``OUT/report/report.md``,
``OUT/report/report.html`` and ``OUT/report/figures/*.png``. Sections whose stage has not
run say so instead of failing, so the report can be looked at while a pipeline runs.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi report``."""
    parser.add_argument("--out", required=True, type=Path, metavar="DIR", help="pipeline output")
    parser.add_argument(
        "--validation",
        type=Path,
        default=None,
        metavar="DIR",
        help="engine validation records (default: OUT/validation)",
    )


def run(args: argparse.Namespace) -> int:
    """Write the report; 0 on success, 2 when --out is not a directory."""
    from rmi_learn.analysis.report import write_report

    # A missing --out is a FileNotFoundError: the entry point reports it (status 2).
    md, page = write_report(args.out, args.validation)
    print(f"wrote {md} and {page}")
    return 0
