"""One grasp-lift-squeeze trial stepped from Python, written as a run file and VTK frames
(``rmi simulate``).

:func:`simulate` writes ``OUT/run.parquet`` (the run-file contract of
:mod:`rmi_learn.data.runs`), ``OUT/config.json`` (the complete trial config) and, with
``vtk_every=N``, ``OUT/trial.pvd`` plus ``OUT/frames/*.vtp`` every N simulator steps (open
``trial.pvd`` in ParaView). The trajectory is recorded by the engine at the same cadence and
with the same load averaging as ``rmi_sph.run_trial``, so both give identical columns.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rmi_learn.data.schema import size_cm
from rmi_learn.errors import InputError
from rmi_learn.sim.progress import TrialProgress

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


#: What :func:`simulate` writes into its output directory (frames go under ``frames/``).
OUTPUTS: tuple[str, ...] = ("run.parquet", "config.json", "trial.pvd", "frames")


def _remove_outputs(out: Path) -> None:
    """Remove what :func:`simulate` writes into ``out`` (nothing else there)."""
    for name in OUTPUTS:
        path = out / name
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)


def simulate(
    config: Any,
    out_dir: str | os.PathLike[str],
    *,
    vtk_every: int = 0,
    num_threads: int | None = None,
    binary: bool = True,
    include_boundary: bool = False,
    surface: bool = False,
    overwrite: bool = False,
    progress: Callable[[TrialProgress], None] | None = None,
) -> dict[str, Any]:
    """Run one scripted trial stepping an ``rmi_sph.Trial`` from Python.

    Writes ``out_dir/run.parquet`` and ``out_dir/config.json`` and, if ``vtk_every > 0``,
    VTK frames every ``vtk_every`` simulator steps (see :mod:`rmi_learn.sim.vtk`). Returns
    ``{"columns", "outcome", "config", "path"}``; columns and outcome have the layout of
    ``rmi_sph.run_trial`` (``wall_s`` includes frame writing).

    An ``out_dir`` that holds a finished run (``run.parquet``) is refused with
    :class:`~rmi_learn.errors.InputError` unless ``overwrite``, which first removes that
    run's outputs (:data:`OUTPUTS`), so no frame of the old run mixes with the new ones.
    ``progress`` is called with a :class:`~rmi_learn.sim.progress.TrialProgress` after
    every chunk of steps (see :class:`~rmi_learn.sim.progress.ProgressLine`).
    When a write fails (a full disk, a read-only directory) the ``OSError`` names the path,
    and the outputs of this call are removed, with ``out_dir`` if this call created it.

    Raises ``rmi_sph.StateError`` if the trial does not finish within its time limit, and
    the engine's errors (``ConfigError``, ``SimulationUnstableError``).
    """
    import rmi_sph

    out = Path(out_dir)
    t0 = time.perf_counter()
    # The config is validated before anything is written: a rejected one leaves no directory.
    sim = rmi_sph.Trial(config, num_threads=num_threads, record=True)
    if (out / "run.parquet").exists() and not overwrite:
        raise InputError(
            f"{out} holds a finished run ({out / 'run.parquet'}); "
            "give --overwrite to replace it, or another --out"
        )
    created = not out.exists()
    if overwrite:
        _remove_outputs(out)
    try:
        return _simulate_into(
            sim,
            out,
            t0,
            vtk_every,
            binary=binary,
            include_boundary=include_boundary,
            surface=surface,
            progress=progress,
        )
    except OSError:
        # Best effort: the error that stopped the writes may stop the clean-up too, and a
        # directory the user filled is not removed (rmdir refuses it).
        with contextlib.suppress(OSError):
            _remove_outputs(out)
            if created:
                out.rmdir()
        raise


def _simulate_into(
    sim: Any,
    out: Path,
    t0: float,
    vtk_every: int,
    *,
    binary: bool,
    include_boundary: bool,
    surface: bool,
    progress: Callable[[TrialProgress], None] | None,
) -> dict[str, Any]:
    """Step ``sim`` to its end writing into ``out`` (see :func:`simulate`)."""
    import rmi_sph
    from rmi_learn.data.runs import atomic_write_json, write_run
    from rmi_learn.sim.vtk import FrameWriter

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
        if progress is not None:
            wall = time.perf_counter() - t0
            progress(TrialProgress(sim.phase, sim.time, limit, sim.step_count, wall))
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
