"""Building the cached dataset from a directory of run files, whole or not at all."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

import rmi_sph
from rmi_learn import __version__
from rmi_learn.data import staging
from rmi_learn.data.dataset.frames import resample_run, select_learning_rows
from rmi_learn.data.dataset.split import SPLITS, grouped_split
from rmi_learn.data.dataset.stats import Stats, compute_stats
from rmi_learn.data.runs import (
    PARAM_KEYS,
    atomic_write_bytes,
    atomic_write_json,
    iter_run_files,
    read_run,
    run_id,
)
from rmi_learn.data.schema import (
    ACTIONS,
    CONTINUOUS,
    CONTROL_ACTIONS,
    CONTROL_DT,
    LEARNING_PHASES,
    OBS,
    WRIST,
    checked_seed,
)
from rmi_learn.errors import input_errors
from rmi_learn.sensing.weight import dry_mass

FORMAT_VERSION = 1


def _collect(run_dir: Path) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Read every run file; return the kept runs (resampled rows) and exclusion counts."""
    kept: list[dict[str, Any]] = []
    counts = {"run_files": 0, "lift_failed": 0, "squeeze_unstable": 0, "no_rows": 0}
    for path in iter_run_files(run_dir):
        counts["run_files"] += 1
        df, meta = read_run(path)
        outcome, params = meta["outcome"], meta["params"]
        if not outcome.get("lift_success", False):
            counts["lift_failed"] += 1
            continue
        if not outcome.get("stable_squeeze", False):
            counts["squeeze_unstable"] += 1
            continue
        grid = resample_run(df)
        keep = select_learning_rows(grid["phase"])
        if not keep.any():
            counts["no_rows"] += 1
            continue
        rows = {name: arr[keep] for name, arr in grid.items()}
        kept.append(
            {
                "run_id": run_id(params),
                "path": path.relative_to(run_dir).as_posix(),
                "params": {k: params[k] for k in PARAM_KEYS},
                "config": meta["config"],
                "rows": rows,
            }
        )
    kept.sort(key=lambda r: r["run_id"])
    return kept, counts


_GRIP_KEYS = frozenset({"controller", "hold_force", "squeeze_force"})


def _dry_masses(configs: list[dict[str, Any]]) -> list[float]:
    """The dry sponge's mass (kg) of each run, for the ``sensors`` mode (what the robot
    weighs before the task): the skeleton's as the engine builds it from the run's config, or
    the config's own ``m_dry`` (a run file of another tool); NaN where neither is there."""
    cache: dict[str, float] = {}
    out = []
    for config in configs:
        given = config.get("m_dry")
        if isinstance(given, int | float) and not isinstance(given, bool):
            out.append(float(given))
            continue
        # The grip's settings do not change the skeleton the engine builds.
        scene = {k: v for k, v in config.items() if k not in _GRIP_KEYS}
        key = json.dumps(scene, sort_keys=True, default=str)
        if key not in cache:
            try:
                cache[key] = dry_mass(rmi_sph.Trial(config, num_threads=1))
            except (ValueError, TypeError, KeyError):
                cache[key] = float("nan")
        out.append(cache[key])
    return out


def build_dataset(
    run_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], seed: int = 0
) -> Path:
    """Build the cached learning dataset from the run files under ``run_dir`` (searched
    recursively for ``run.parquet``) into ``out_dir`` and return ``out_dir``.

    See the module docstring for the selection, resampling, split and statistics rules.
    Raises FileNotFoundError if ``run_dir`` is not a directory, ValueError if ``seed`` is
    not in [0, SEED_MAX], no run qualifies or the training split is empty.
    """
    seed = checked_seed(seed)
    run_dir, out = Path(run_dir), Path(out_dir)
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir} is not a directory of runs")
    kept, counts = _collect(run_dir)
    if not kept:
        raise ValueError(f"no run under {run_dir} completed lift and squeeze with a stable grasp")

    params = pl.DataFrame([r["params"] for r in kept]).with_columns(
        pl.col("size_cm").cast(pl.Int64),
        pl.col("porosity").cast(pl.Float64),
        pl.col("F_hold").cast(pl.Float64),
        pl.col("F_squeeze").cast(pl.Float64),
        pl.col("seed").cast(pl.Int64),
    )
    split = grouped_split(params, seed)

    frames: list[pl.DataFrame] = []
    seg_base = 0
    n_rows, n_segs = [], []
    for i, r in enumerate(kept):
        rows = r["rows"]
        n = rows["k"].size
        seg = np.concatenate([[0], np.cumsum(np.diff(rows["k"]) != 1)]).astype(np.int64)
        cols: dict[str, Any] = {
            "run": np.full(n, i, dtype=np.int32),
            "t": np.arange(n, dtype=np.int32),
            "k": rows["k"],
            "segment": seg + seg_base,
            "time": rows["time"],
            "phase": rows["phase"],
        }
        cols.update({name: rows[name] for name in OBS + ACTIONS + WRIST if name in rows})
        frames.append(pl.DataFrame(cols))
        seg_base += int(seg[-1]) + 1
        n_rows.append(n)
        n_segs.append(int(seg[-1]) + 1)
    frame = pl.concat(frames)

    runs = params.with_columns(
        pl.Series("run", np.arange(len(kept), dtype=np.int32)),
        pl.Series("run_id", [r["run_id"] for r in kept]),
        pl.Series("path", [r["path"] for r in kept]),
        pl.Series("split", split),
        pl.Series("n_rows", n_rows, dtype=pl.Int64),
        pl.Series("n_segments", n_segs, dtype=pl.Int64),
        pl.Series("m_dry", _dry_masses([r["config"] for r in kept]), dtype=pl.Float64),
    ).select("run", "run_id", *PARAM_KEYS, "split", "n_rows", "n_segments", "m_dry", "path")

    train_runs = np.flatnonzero(np.asarray(split) == "train")
    if train_runs.size == 0:
        raise ValueError("the training split is empty")
    train = frame.filter(pl.col("run").is_in(train_runs.tolist()))
    stats = compute_stats(
        train.select(CONTINUOUS).to_numpy().astype(np.float64),
        train.select(CONTROL_ACTIONS).to_numpy().astype(np.float64),
    )

    per_split = {
        s: {
            "runs": int(runs.filter(pl.col("split") == s).height),
            "rows": int(runs.filter(pl.col("split") == s)["n_rows"].sum()),
        }
        for s in SPLITS
    }
    info = {
        "format": FORMAT_VERSION,
        "version": __version__,
        "source": str(run_dir.resolve()),
        "seed": seed,
        "dt": CONTROL_DT,
        "learning_phases": list(LEARNING_PHASES),
        "resampling": "linear interpolation (continuous), zero-order hold (categorical)",
        "counts": {**counts, "kept": len(kept), "rows": frame.height},
        "splits": per_split,
    }
    _write_build(out, frame, runs, stats, info)
    return out


#: The files of a built dataset in the order they are moved into place: ``dataset.json``
#: last, as it marks a complete build.
BUILD_FILES = ("frames.parquet", "runs.parquet", "stats.json", "dataset.json")


def _write_build(
    out: Path, frame: pl.DataFrame, runs: pl.DataFrame, stats: Stats, info: dict[str, Any]
) -> None:
    """Write the dataset's files into ``out``, whole or not at all: they are written into a
    temporary directory inside ``out`` and moved in together, so an error (a full disk)
    leaves an existing ``out`` as it was and removes an ``out`` this build created."""
    with staging.staged(out, "build", out) as tmp:
        frames_data, runs_data = staging.parquet_bytes(frame), staging.parquet_bytes(runs)
        atomic_write_bytes(tmp / "frames.parquet", lambda f: f.write(frames_data))
        atomic_write_bytes(tmp / "runs.parquet", lambda f: f.write(runs_data))
        atomic_write_json(tmp / "stats.json", stats.to_json())
        atomic_write_json(tmp / "dataset.json", info)
        staging.move_in(tmp, out, list(BUILD_FILES))


@input_errors(OSError, ValueError)
def build(run_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str], seed: int = 0) -> Path:
    """``rmi dataset build``: :func:`build_dataset`, with a run tree that yields no dataset
    or an output directory that cannot be written reported as
    :class:`~rmi_learn.errors.InputError`."""
    return build_dataset(run_dir, out_dir, seed=seed)
