"""One grasp-lift-squeeze trial stepped from Python, written as a run file and VTK frames
(``rmi simulate``).

:func:`simulate` writes ``OUT/run.parquet`` (the run-file contract of
:mod:`rmi_learn.data.runs`), ``OUT/config.json`` (the complete trial config) and, with
``vtk_every=N``, ``OUT/trial.pvd`` plus ``OUT/frames/*.vtp`` every N simulator steps (open
``trial.pvd`` in ParaView). The trajectory is recorded by the engine at the same cadence and
with the same load averaging as ``rmi_sph.run_trial``, so both give identical columns.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from rmi_learn.data.schema import size_cm
from rmi_learn.errors import InputError

#: Steps per ``Trial.step`` call when no frames are written (only the chunk of Ctrl-C
#: checks and progress; results do not depend on it).
_CHUNK = 200


def params_of(config: dict[str, Any]) -> dict[str, Any]:
    """Run parameters (``rmi.params``) of a trial config: size_cm from the sponge's x size."""
    return {
        "size_cm": size_cm(config["size"]),
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
    """Run one scripted trial stepping an ``rmi_sph.Trial`` from Python.

    Writes ``out_dir/run.parquet`` and ``out_dir/config.json`` and, if ``vtk_every > 0``,
    VTK frames every ``vtk_every`` simulator steps (see :mod:`rmi_learn.sim.vtk`). Returns
    ``{"columns", "outcome", "config", "path"}``; columns and outcome have the layout of
    ``rmi_sph.run_trial`` (``wall_s`` includes frame writing).

    Raises ``rmi_sph.StateError`` if the trial does not finish within its time limit, and
    the engine's errors (``ConfigError``, ``SimulationUnstableError``).
    """
    import rmi_sph
    from rmi_learn.data.runs import atomic_write_json, write_run
    from rmi_learn.sim.vtk import FrameWriter

    out = Path(out_dir)
    t0 = time.perf_counter()
    # The config is validated before anything is written: a rejected one leaves no directory.
    sim = rmi_sph.Trial(config, num_threads=num_threads, record=True)
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


def read_config(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A trial config from a JSON file: a JSON object, as given (``simulate`` checks its
    fields). Raises :class:`~rmi_learn.errors.InputError` when the file is not UTF-8 JSON,
    nests deeper than the parser allows, or holds anything but an object."""
    from rmi_learn.data.runs import json_kind, read_json_source

    try:
        config, _ = read_json_source(__package__, (), None, path, "trial config")
    except ValueError as exc:
        raise InputError(exc) from exc
    if not isinstance(config, dict):
        raise InputError(f"{path}: a trial config is a JSON object, got {json_kind(config)}")
    return config
