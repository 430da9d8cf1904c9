"""The sweep driver: every run of a grid that is not done yet computed into one output
directory, on the local or the Ray backend (:func:`run_sweep`), and ``rmi sweep`` from a
grid preset or file (:func:`sweep`)."""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl
from tqdm.auto import tqdm  # type: ignore[import-untyped]

import rmi_sph
from rmi_learn.data.output_lock import output_lock
from rmi_learn.data.runs import atomic_write_json, run_path
from rmi_learn.data.schema import size_cm
from rmi_learn.data.sweep.compute import Runner, RunSettings, is_done, prefix_groups
from rmi_learn.data.sweep.configs import ConfigMaker, check_stale, configs_of
from rmi_learn.data.sweep.grid import RunSpec, expand_grid, load_grid
from rmi_learn.data.sweep.index import RUNS_SUBDIR, build_index
from rmi_learn.data.sweep.local import run_local
from rmi_learn.data.sweep.lock import LOCK_NAME, clean_temporaries
from rmi_learn.data.sweep.ray_runner import run_ray
from rmi_learn.errors import InputError, StageFailure

GRID_FILE = "grid.json"


@dataclass
class SweepResult:
    """Counts of one sweep call and the index it left behind."""

    total: int
    skipped: int
    ok: int
    failed: int
    unstable: int
    wall_s: float
    index: pl.DataFrame

    def summary(self) -> str:
        return (
            f"{self.total} runs: {self.skipped} already done, {self.ok} ok, "
            f"{self.failed} failed, {self.unstable} unstable in {self.wall_s:.1f} s"
        )


class _Progress:
    """The counts of the runs a sweep finished, and its progress bar (runs done, failures,
    ETA), which prints each failure as it is recorded."""

    def __init__(self, total: int, done: int, show: bool) -> None:
        self.counts = {"ok": 0, "failed": 0, "unstable": 0}
        self.bar = tqdm(
            total=total,
            initial=done,
            desc="sweep",
            unit="run",
            disable=not show,
            dynamic_ncols=True,
        )

    def record(self, res: Mapping[str, Any]) -> None:
        st = res["status"]
        if st in self.counts:
            self.counts[st] += 1
        if st in ("failed", "unstable"):
            self.bar.write(f"[{st}] {res['run_id']}: {res['error']}")
        self.bar.update(1)
        self.bar.set_postfix(
            failed=self.counts["failed"], unstable=self.counts["unstable"], refresh=False
        )


def _check_grid_file(out: Path, grid: Mapping[str, Any] | None) -> None:
    """Store ``grid`` as ``OUT/grid.json`` on the first sweep into ``out``; refuse another
    grid on a later one."""
    if grid is None:
        return
    gpath = out / GRID_FILE
    if gpath.exists():
        old = json.loads(gpath.read_text())
        if old != json.loads(json.dumps(grid)):
            raise ValueError(
                f"{out} holds a sweep of another grid ({gpath}); use a new --out directory "
                "or remove grid.json if the runs may be mixed"
            )
    else:
        atomic_write_json(gpath, grid)


def run_sweep(
    specs: Iterable[RunSpec],
    out_dir: str | os.PathLike[str],
    *,
    runner: Runner | None = None,
    make_config: ConfigMaker = rmi_sph.trial_config,
    backend: str = "local",
    workers: int | None = None,
    threads_per_run: int = 1,
    retry_failed: bool = False,
    progress: bool = True,
    grid: Mapping[str, Any] | None = None,
) -> SweepResult:
    """Execute every run of ``specs`` that is not done into ``out_dir`` and rebuild the index.

    ``backend`` ``"local"``: a process pool of ``workers`` spawned processes (default
    ``cpu_count // threads_per_run``; ``workers=0`` runs in this process, for debugging).
    ``"ray"``: one Ray task per run with ``num_cpus=threads_per_run`` (``ray.init()`` on the
    local machine, or the cluster named by ``$RAY_ADDRESS``). Each run gets
    ``num_threads=threads_per_run``. Prints a tqdm progress bar (runs done, failures, ETA)
    unless ``progress`` is false. ``grid`` is stored as ``grid.json`` on the first sweep
    and must match on later ones. ``runner`` runs each trial (None: the engine's
    ``rmi_sph.run_trial``, whose runs that differ only in their squeeze force share one
    prefix); ``make_config`` builds each run's trial config.
    """
    specs = list(specs)
    configs = configs_of(specs, make_config)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with output_lock(out, LOCK_NAME):
        _check_grid_file(out, grid)
        clean_temporaries(out)
        settings = RunSettings(str(out / RUNS_SUBDIR), runner, threads_per_run, retry_failed)
        return _sweep_locked(specs, configs, out, settings, backend, workers, progress)


def _sweep_locked(
    specs: list[RunSpec],
    configs: Mapping[str, dict[str, Any]],
    out: Path,
    settings: RunSettings,
    backend: str,
    workers: int | None,
    progress: bool,
) -> SweepResult:
    """:func:`run_sweep` once it holds the output directory."""
    _check_specs(specs, settings.threads_per_run)
    check_stale(specs, Path(settings.runs_root), configs)
    pending = _pending(specs, settings)
    groups = prefix_groups(pending, configs, settings.runner)
    t0 = time.perf_counter()
    bar = _Progress(len(specs), len(specs) - len(pending), progress)
    try:
        if pending:
            _dispatch(groups, configs, settings, backend, workers, bar)
    finally:
        bar.bar.close()
        index = build_index(out)
    return SweepResult(
        total=len(specs),
        skipped=len(specs) - len(pending),
        ok=bar.counts["ok"],
        failed=bar.counts["failed"],
        unstable=bar.counts["unstable"],
        wall_s=time.perf_counter() - t0,
        index=index,
    )


def _check_specs(specs: list[RunSpec], threads_per_run: int) -> None:
    ids = [s.run_id for s in specs]
    if len(set(ids)) != len(ids):
        raise ValueError("the grid names some runs twice")
    if threads_per_run < 1:
        raise ValueError("threads_per_run must be at least 1")


def _pending(specs: list[RunSpec], settings: RunSettings) -> list[RunSpec]:
    """The runs of ``specs`` that are not done, the longest first."""
    root, retry = settings.runs_root, settings.retry_failed
    return longest_first([s for s in specs if not is_done(run_path(root, s.params).parent, retry)])


def _dispatch(
    groups: list[list[RunSpec]],
    configs: Mapping[str, dict[str, Any]],
    settings: RunSettings,
    backend: str,
    workers: int | None,
    progress: _Progress,
) -> None:
    """Run every group on ``backend``, telling ``progress`` of each run's result."""
    if backend == "local":
        n = (
            workers
            if workers is not None
            else max(1, (os.cpu_count() or 1) // settings.threads_per_run)
        )
        if n <= 0:
            for g in groups:
                for res in settings.execute(g, configs):
                    progress.record(res)
        else:
            run_local(groups, configs, settings, n, progress.record)
    elif backend == "ray":
        run_ray(groups, configs, settings, workers, progress.record)
    else:
        raise ValueError(f"unknown backend {backend!r} (local or ray)")


def longest_first(specs: list[RunSpec]) -> list[RunSpec]:
    """``specs`` with the most particles first (the largest sponge, the finest radius), grid
    order kept among equals: started last, a long trial would keep one worker busy while the
    others idle. Each run's result does not depend on the order."""
    volume = {size_cm(d): d[0] * d[1] * d[2] for d in rmi_sph.SPONGE_SIZES_M}

    def particles(s: RunSpec) -> float:
        return volume.get(int(s.params["size_cm"]), 0.0) / s.radius**3

    return sorted(specs, key=lambda s: -particles(s))


def estimate_wall_time(per_run_s: float, runs: int, workers: int) -> float:
    """Wall time (s) of ``runs`` runs of ``per_run_s`` seconds each on ``workers`` parallel
    workers (whole waves, no overhead)."""
    return math.ceil(runs / max(1, workers)) * per_run_s


def sweep(
    out_dir: str | os.PathLike[str],
    *,
    preset: str | None = None,
    grid_file: str | os.PathLike[str] | None = None,
    limit: int | None = None,
    backend: str = "local",
    workers: int | None = None,
    threads_per_run: int = 1,
    retry_failed: bool = False,
    progress: bool = True,
    runner: Runner | None = None,
    make_config: ConfigMaker = rmi_sph.trial_config,
) -> SweepResult:
    """``rmi sweep``: run the grid of ``preset`` or ``grid_file`` (exactly one), or its first
    ``limit`` points, into ``out_dir`` (see :func:`run_sweep` for the other arguments).

    Raises :class:`~rmi_learn.errors.InputError` for a missing or bad grid and a run the
    engine refuses, :class:`~rmi_learn.errors.StageFailure` when the sweep cannot start
    (another sweep holds the lock, the ray backend is missing)."""
    if not preset and not grid_file:
        raise InputError("give --preset NAME or --grid FILE")
    try:
        grid = load_grid(preset=preset) if preset else load_grid(path=grid_file)
    except (OSError, ValueError) as exc:
        raise InputError(exc) from exc
    specs = expand_grid(grid)
    if limit is not None:
        specs = specs[:limit]
    try:
        return run_sweep(
            specs,
            out_dir,
            runner=runner,
            make_config=make_config,
            backend=backend,
            workers=workers,
            threads_per_run=threads_per_run,
            retry_failed=retry_failed,
            progress=progress,
            grid=grid,
        )
    except ValueError as exc:
        raise InputError(exc) from exc
    except RuntimeError as exc:
        raise StageFailure(exc) from exc
