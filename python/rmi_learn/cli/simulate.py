"""``rmi simulate``: run one grasp-lift-squeeze trial, write its run file and VTK frames.

Examples::

    rmi simulate --config trial.json --out out/one --vtk-every 20 --threads 2
    rmi simulate --size 10 --porosity 0.6 --hold 40 --squeeze 80 --out out/one

Writes ``OUT/run.parquet``, ``OUT/config.json`` and, with ``--vtk-every N``, ``OUT/trial.pvd``
plus ``OUT/frames/*.vtp`` (see :mod:`rmi_learn.sim.trial`). Prints the outcome as JSON, and
while the trial runs a progress line on stderr every few seconds (phase, simulated time,
steps per second; ``--quiet`` turns it off).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from rmi_learn.cli.threads import add_threads, threads_of
from rmi_learn.data.schema import SPONGE_SIZES_CM
from rmi_learn.errors import StageFailure
from rmi_learn.option_types import count, seed

#: Seconds between progress lines on a terminal (rewritten in place) and in a log file.
PROGRESS_EVERY_S = {True: 1.0, False: 5.0}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``rmi simulate``."""
    parser.add_argument(
        "--config", type=Path, help="trial config JSON file (default: built from the options below)"
    )
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--vtk-every",
        type=count(0),
        default=0,
        metavar="N",
        help="write a VTK frame every N simulator steps (0: none)",
    )
    parser.add_argument("--vtk-ascii", action="store_true", help="ascii instead of binary VTK")
    parser.add_argument(
        "--vtk-boundary", action="store_true", help="include floor/pad particles in frames"
    )
    parser.add_argument(
        "--surface",
        action="store_true",
        help="reconstruct the water surface per frame with pysplashsurf (if installed)",
    )
    add_threads(parser, "the engine")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a finished run in --out (refused otherwise)",
    )
    parser.add_argument(
        "--quiet",
        "--no-progress",
        action="store_true",
        help="no progress line on stderr while the trial runs",
    )
    g = parser.add_argument_group("config from parameters (when no --config is given)")
    g.add_argument("--size", type=int, choices=SPONGE_SIZES_CM, default=10, help="sponge size (cm)")
    g.add_argument("--porosity", type=float, default=0.6, help="porosity (-)")
    g.add_argument("--hold", type=float, default=40.0, help="holding force (N)")
    g.add_argument("--squeeze", type=float, default=80.0, help="squeeze force (N)")
    g.add_argument("--radius", type=float, default=0.005, help="particle radius (m)")
    g.add_argument("--seed", type=seed, default=0, help="seed of the pore-water jitter")
    g.add_argument(
        "--dt", type=float, default=None, help="time step (s) (default: the config's, 1 ms)"
    )


def run(args: argparse.Namespace) -> int:
    import rmi_sph
    from rmi_learn.sim.trial import read_config, simulate

    # A missing file or a config value out of range is reported by the `rmi` entry point.
    if args.config is not None:
        config: Any = read_config(args.config)
    else:
        extra = {} if args.dt is None else {"dt": args.dt}
        config = rmi_sph.trial_config(
            args.size, args.porosity, args.hold, args.squeeze, args.radius, args.seed, **extra
        )
    from rmi_learn.sim.progress import ProgressLine

    line = None
    if not args.quiet:
        tty = sys.stderr.isatty()
        line = ProgressLine(sys.stderr, prefix="rmi simulate: ", every_s=PROGRESS_EVERY_S[tty])
    try:
        result = simulate(
            config,
            args.out,
            vtk_every=args.vtk_every,
            num_threads=threads_of(args.threads),
            binary=not args.vtk_ascii,
            include_boundary=args.vtk_boundary,
            surface=args.surface,
            overwrite=args.overwrite,
            progress=line,
        )
    except rmi_sph.ConfigError:
        raise  # bad input: reported by the `rmi` entry point (status 2)
    except rmi_sph.RmiError as exc:
        raise StageFailure(f"{type(exc).__name__}: {exc}") from exc
    finally:
        if line is not None:
            line.close()
    if args.surface:
        from rmi_learn.sim.vtk import surface_available

        if not surface_available():
            print("rmi simulate: pysplashsurf is not installed; no surfaces", file=sys.stderr)
    print(json.dumps(result["outcome"], indent=2, sort_keys=True))
    print(f"run file: {result['path']}", file=sys.stderr)
    return 0
