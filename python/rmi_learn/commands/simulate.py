"""``rmi simulate``: run one grasp-lift-squeeze trial, write its run file and VTK frames.

Examples::

    rmi simulate --config trial.json --out out/one --vtk-every 20 --threads 2
    rmi simulate --size 10 --porosity 0.6 --hold 40 --squeeze 80 --out out/one

Writes ``OUT/run.parquet`` (the run-file contract of ``rmi_learn.runs``), ``OUT/config.json``
(the complete trial config) and, with ``--vtk-every N``, ``OUT/trial.pvd`` plus
``OUT/frames/*.vtp`` every N simulator steps (open ``trial.pvd`` in ParaView). Prints the
outcome as JSON. The trajectory is recorded by the engine at the same cadence and with the
same load averaging as ``rmi_sph.run_trial``, so both give identical columns.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from rmi_learn.commands import InputError
from rmi_learn.commands.argtypes import count

#: Steps per ``Simulation.step`` call when no frames are written (only the chunk of Ctrl-C
#: checks and progress; results do not depend on it).
_CHUNK = 200


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="trial config JSON file")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument(
        "--vtk-every", type=count(0), default=0, help="write a VTK frame every N simulator steps"
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
    parser.add_argument("--threads", type=count(1), default=None, help="worker threads")
    g = parser.add_argument_group("config from parameters (when no --config is given)")
    g.add_argument("--size", type=int, choices=(8, 10, 12), default=10, help="sponge size (cm)")
    g.add_argument("--porosity", type=float, default=0.6, help="porosity (-)")
    g.add_argument("--hold", type=float, default=40.0, help="holding force (N)")
    g.add_argument("--squeeze", type=float, default=80.0, help="squeeze force (N)")
    g.add_argument("--radius", type=float, default=0.005, help="particle radius (m)")
    g.add_argument("--seed", type=count(0), default=0, help="seed of the pore-water jitter")
    g.add_argument("--dt", type=float, default=None, help="time step (s)")


def params_of(config: dict[str, Any]) -> dict[str, Any]:
    """Run parameters (``rmi.params``) of a trial config: size_cm from the sponge's x size."""
    return {
        "size_cm": int(round(float(config["size"][0]) * 100)),
        "porosity": float(config["porosity"]),
        "F_hold": float(config["hold_force"]),
        "F_squeeze": float(config["squeeze_force"]),
        "seed": int(config["seed"]),
    }


def simulate(
    config: Any,
    out_dir: str | os.PathLike[str],
    *,
    vtk_every: int = 0,
    num_threads: int | None = None,
    binary: bool = True,
    include_boundary: bool = False,
    surface: bool = False,
) -> dict[str, Any]:
    """Run one scripted trial stepping an ``rmi_sph.Simulation`` from Python.

    Writes ``out_dir/run.parquet`` and ``out_dir/config.json`` and, if ``vtk_every > 0``,
    VTK frames every ``vtk_every`` simulator steps (see :mod:`rmi_learn.vtk`). Returns
    ``{"columns", "outcome", "config", "path"}``; columns and outcome have the layout of
    ``rmi_sph.run_trial`` (``wall_s`` includes frame writing).

    Raises ``rmi_sph.StateError`` if the trial does not finish within its time limit, and
    the engine's errors (``ConfigError``, ``SimulationUnstableError``).
    """
    import rmi_sph
    from rmi_learn.runs import atomic_write_json, write_run
    from rmi_learn.vtk import FrameWriter

    out = Path(out_dir)
    t0 = time.perf_counter()
    # The config is validated before anything is written: a rejected one leaves no directory.
    sim = rmi_sph.Simulation(config, num_threads=num_threads, record=True)
    out.mkdir(parents=True, exist_ok=True)
    cfg = sim.config
    atomic_write_json(out / "config.json", cfg)
    writer = (
        FrameWriter(out, binary=binary, include_boundary=include_boundary, surface=surface)
        if vtk_every > 0
        else None
    )
    if writer is not None:
        writer.write(sim)
    limit = sim.time_limit
    chunk = vtk_every if vtk_every > 0 else _CHUNK
    while not sim.finished:
        taken = sim.step(chunk, stop_at_finish=True)
        if writer is not None and taken > 0:
            writer.write(sim)
        if not sim.finished and sim.time > limit:
            raise rmi_sph.StateError(f"trial did not finish within its time limit of {limit:.2f} s")
    columns = sim.records()
    outcome = sim.outcome()
    outcome["wall_s"] = time.perf_counter() - t0
    path = write_run(out / "run.parquet", columns, cfg, params_of(cfg), outcome)
    return {"columns": columns, "outcome": outcome, "config": cfg, "path": path}


def run(args: argparse.Namespace) -> int:
    import rmi_sph

    # A missing file or a config value out of range is reported by the `rmi` entry point.
    if args.config is not None:
        try:
            config: Any = json.loads(Path(args.config).read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise InputError(f"{args.config}: not valid JSON: {exc}") from exc
    else:
        extra = {} if args.dt is None else {"dt": args.dt}
        config = rmi_sph.trial_config(
            args.size, args.porosity, args.hold, args.squeeze, args.radius, args.seed, **extra
        )
    try:
        result = simulate(
            config,
            args.out,
            vtk_every=args.vtk_every,
            num_threads=args.threads,
            binary=not args.vtk_ascii,
            include_boundary=args.vtk_boundary,
            surface=args.surface,
        )
    except rmi_sph.ConfigError:
        raise  # bad input: reported by the `rmi` entry point (status 2)
    except rmi_sph.RmiError as exc:
        print(f"rmi simulate: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    if args.surface:
        from rmi_learn.vtk import surface_available

        if not surface_available():
            print("rmi simulate: pysplashsurf is not installed; no surfaces", file=sys.stderr)
    print(json.dumps(result["outcome"], indent=2, sort_keys=True))
    print(f"run file: {result['path']}", file=sys.stderr)
    return 0
