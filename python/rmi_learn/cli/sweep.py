"""``rmi sweep``: run a grid of trials into a directory, resumable, local or Ray workers."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.data import sweep as sweeps
from rmi_learn.errors import InputError
from rmi_learn.option_types import count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi sweep``."""
    src = parser.add_mutually_exclusive_group()
    src.add_argument("--preset", choices=sweeps.PRESETS, help="a built-in grid")
    src.add_argument("--grid", metavar="FILE", help="a grid JSON file (same keys as the presets)")
    parser.add_argument("--out", required=True, metavar="DIR", help="output directory")
    parser.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="local: a process pool on this machine; ray: one Ray task per run (a Ray started "
        "here, or the cluster of $RAY_ADDRESS)",
    )
    add_threads(parser, "the whole sweep on this machine: --workers x --threads-per-run")
    parser.add_argument(
        "--workers",
        type=count(0),
        default=None,
        help="parallel runs (local: processes; 0 runs in this process) "
        "(default: --threads // --threads-per-run, at least 1)",
    )
    parser.add_argument(
        "--threads-per-run", type=count(1), default=1, metavar="K", help="engine threads per run"
    )
    parser.add_argument(
        "--retry-failed", action="store_true", help="rerun runs recorded as failed or unstable"
    )
    parser.add_argument(
        "--limit",
        type=count(0),
        default=None,
        metavar="N",
        help="run only the first N grid points (default: every point)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--index-only", action="store_true", help="only rebuild OUT/index.parquet from the runs"
    )
    # Test hooks: "module:function" replacing rmi_sph.run_trial / rmi_sph.trial_config.
    parser.add_argument("--runner", type=_function, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--make-config", type=_function, default=None, help=argparse.SUPPRESS)


def _function(ref: str) -> Callable[..., Any]:
    """The function a ``module:function`` reference names, imported; a usage error naming
    the reference when it cannot be loaded."""
    module, _, attr = ref.partition(":")
    try:
        function: Callable[..., Any] = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError, ValueError) as exc:
        raise argparse.ArgumentTypeError(f"cannot load {ref!r}: {exc}") from None
    return function


def run(args: argparse.Namespace) -> int:
    """Execute the sweep; exit status 0 when every run of the grid has a run file or a
    recorded failure, 2 on bad input (options, grid file, a run the engine refuses), 1 when
    the sweep cannot start (another sweep holds the lock, the ray backend is missing)."""
    if args.index_only:
        # Only an existing sweep's index is rebuilt: a mistyped --out must not appear empty.
        if not Path(args.out).is_dir():
            raise InputError(f"{args.out} is not a sweep directory (--index-only needs one)")
        df = sweeps.build_index(args.out)
        print(f"index: {df.height} runs -> {args.out}/index.parquet")
        return 0
    workers = args.workers
    # A Ray cluster sizes itself; a local pool (or a Ray started here) fills --threads.
    if workers is None and (args.backend == "local" or args.threads is not None):
        workers = max(1, threads_of(args.threads) // args.threads_per_run)
    # The library's defaults (the engine's functions) unless a test hook replaces them.
    hooks = {"runner": args.runner, "make_config": args.make_config}
    res = sweeps.sweep(
        args.out,
        preset=args.preset,
        grid_file=args.grid,
        limit=args.limit,
        backend=args.backend,
        workers=workers,
        threads_per_run=args.threads_per_run,
        retry_failed=args.retry_failed,
        progress=not args.no_progress,
        **{name: function for name, function in hooks.items() if function is not None},
    )
    print(res.summary())
    print(f"index: {args.out}/index.parquet")
    return 0
