"""The run table of a grid: one row per run, read from ``index.parquet`` or rebuilt from the
run files (:func:`load_runs`), with the phases each run reached; the rows the analysis counts
(:func:`ok_runs`, :func:`reached_mask`) and the run it plots (:func:`choose_representative`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data.runs import (
    ERROR_FILE,
    RUN_FILE,
    check_run_schema,
    read_run_meta,
)
from rmi_learn.data.sweep import INDEX_FILE, INDEX_SCHEMA, RUNS_SUBDIR, build_index, index_frame
from rmi_learn.errors import InputError, RunFileError

#: Phases whose water removal is analysed. ``settle`` precedes contact and ``done`` is the
#: release, so neither is a transport phase of the grasp.
ANALYSIS_PHASES: tuple[str, ...] = ("close", "ramp", "hold", "lift", "waiting", "squeeze")


class AnalysisError(InputError, ValueError):
    """The input directory cannot be analysed (missing, empty, unreadable, unknown run)."""


@dataclass
class RunTable:
    """One row per run with the columns of :func:`rmi_learn.data.sweep.build_index`, plus
    ``reached_<phase>`` (bool, null without a run file) for :data:`ANALYSIS_PHASES` and
    ``source`` (the run config's ``source`` or null)."""

    index: pl.DataFrame
    #: Directory the index's ``path`` column is relative to.
    base: Path
    #: ``index.parquet``, ``sweep tree`` or ``bare runs tree``.
    origin: str


def _normalise_index(df: pl.DataFrame | None) -> pl.DataFrame:
    """Give an index every column the analysis reads, with fixed types (a grid where, say,
    no run failed has an all-null ``failure`` column of unknown type)."""
    types = INDEX_SCHEMA
    if df is None:
        df = pl.DataFrame(schema=types)
    df = df.with_columns(
        [
            pl.col(c).cast(t, strict=False) if c in df.columns else pl.lit(None, t).alias(c)
            for c, t in types.items()
        ]
    )
    return df.sort("run_id") if df.height else df


def _run_facts(path: Path) -> tuple[set[str] | None, str | None]:
    """Phases a run file visits and its config ``source`` (``None`` if unreadable). Raises
    :class:`RunFileError` for a readable file whose columns break the run-file contract."""
    try:
        schema = pl.read_parquet_schema(path)
    except (OSError, pl.exceptions.PolarsError):
        return None, None
    check_run_schema(path, schema)
    try:
        phases = pl.read_parquet(path, columns=["phase"])["phase"].unique().to_list()
        source = read_run_meta(path)["config"].get("source")
    except (OSError, RunFileError, pl.exceptions.PolarsError):
        return None, None
    return {str(p) for p in phases}, None if source is None else str(source)


def load_runs(runs_dir: str | os.PathLike[str]) -> RunTable:
    """Read the runs of ``runs_dir``: its ``index.parquet`` if present, else the index
    rebuilt from ``runs_dir/runs`` (a sweep directory) or from ``runs_dir`` itself (a bare
    runs tree), without the runs that followed perturbed force targets. The engine records
    0 kg for phases a run never reached, so which phases a run visited is read from each run
    file's ``phase`` column.

    Raises :class:`AnalysisError` when the directory is missing, holds no run or cannot be
    read."""
    root = Path(runs_dir)
    if not root.exists():
        raise AnalysisError(f"{root} does not exist")
    if not root.is_dir():
        raise AnalysisError(f"{root} is not a directory")
    try:
        if (root / INDEX_FILE).is_file():
            index, origin = _normalise_index(pl.read_parquet(root / INDEX_FILE)), INDEX_FILE
        elif (root / RUNS_SUBDIR).is_dir():
            index, origin = _normalise_index(build_index(root, write=False)), "sweep tree"
        else:
            index, origin = _normalise_index(index_frame(root, root)), "bare runs tree"
    except (OSError, KeyError, ValueError, pl.exceptions.PolarsError) as exc:
        raise AnalysisError(f"cannot read the runs of {root}: {exc}") from exc
    if index.height == 0:
        raise AnalysisError(
            f"{root} holds no runs (expected {INDEX_FILE}, {RUNS_SUBDIR}/ or a tree of "
            f"{RUN_FILE} / {ERROR_FILE} files)"
        )
    # The tables relate water removed to the scripted squeeze force; runs that followed
    # perturbed force targets from the lift on (data for the world models) have none.
    index = index.filter(~pl.col("perturbed").fill_null(False))
    if index.height == 0:
        raise AnalysisError(f"{root} holds only runs with perturbed force targets")
    reached: dict[str, list[bool | None]] = {ph: [] for ph in ANALYSIS_PHASES}
    sources: list[str | None] = []
    for rel, status in zip(index["path"].to_list(), index["status"].to_list(), strict=True):
        phases: set[str] | None = None
        source: str | None = None
        if status == "ok" and rel is not None and str(rel).endswith(RUN_FILE):
            phases, source = _run_facts(root / str(rel))
        for ph in ANALYSIS_PHASES:
            reached[ph].append(None if phases is None else ph in phases)
        sources.append(source)
    index = index.with_columns(
        [pl.Series(f"reached_{ph}", v, dtype=pl.Boolean) for ph, v in reached.items()]
        + [pl.Series("source", sources, dtype=pl.String)]
    )
    return RunTable(index=index, base=root, origin=origin)


def ok_runs(index: pl.DataFrame) -> pl.DataFrame:
    """The rows of runs whose status is ``ok`` (they have a usable run file)."""
    return index.filter(pl.col("status") == "ok")


def reached_mask(index: pl.DataFrame, phase: str) -> np.ndarray:
    """Rows that reached ``phase``: from the run file where known, else a recorded value."""
    has_value = index[f"water_removed_{phase}"].is_not_null().to_numpy()
    col = f"reached_{phase}"
    if col not in index.columns:
        return np.asarray(has_value, dtype=bool)
    known = index[col].to_list()
    return np.array(
        [
            bool(v) and bool(k) if k is not None else bool(v)
            for v, k in zip(has_value, known, strict=True)
        ],
        dtype=bool,
    )


def _median_of_values(values: Sequence[float]) -> float:
    return float(np.median(np.unique(np.asarray(values, dtype=float))))


def choose_representative(
    table: RunTable, run_id: str | None = None
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The run plotted in Fig. 4 and why: ``run_id`` if given, else the ``ok`` run with lift
    success and a stable squeeze whose parameters (size, porosity, holding and squeeze
    force, each scaled by its range over the grid) lie closest to the median of the grid's
    distinct values; ties go to the smaller seed, then the run id. Raises
    :class:`AnalysisError` for an unknown ``run_id`` or one without a run file."""
    idx = table.index
    if run_id is not None:
        rows = idx.filter(pl.col("run_id") == run_id).to_dicts()
        if not rows:
            raise AnalysisError(f"no run {run_id!r} in {table.base}")
        row = rows[0]
        if row["status"] != "ok" or not str(row["path"]).endswith(RUN_FILE):
            raise AnalysisError(f"run {run_id!r} has no run file (status {row['status']})")
        return row, {"rule": "chosen with --run-id"}
    ok = ok_runs(idx)
    keys = ("size_cm", "porosity", "F_hold", "F_squeeze")
    target = {k: _median_of_values(ok[k].to_list()) for k in keys} if ok.height else {}
    cand = ok.filter(
        pl.col("lift_success").fill_null(False) & pl.col("stable_squeeze").fill_null(False)
    )
    if cand.height == 0:
        return {}, {"rule": "none: no run with lift success and a stable squeeze"}
    dist = np.zeros(cand.height)
    for k in keys:
        vals = ok[k].to_numpy().astype(float)
        span = float(vals.max() - vals.min())
        if span > 0:
            dist += ((cand[k].to_numpy().astype(float) - target[k]) / span) ** 2
    order = sorted(
        range(cand.height),
        key=lambda i: (round(float(dist[i]), 12), cand["seed"][i], cand["run_id"][i]),
    )
    row = cand.row(order[0], named=True)
    return row, {
        "rule": "lift success and stable squeeze, closest to the grid's median parameters "
        "(each scaled by its range)",
        "grid_median": target,
        "distance": float(math.sqrt(dist[order[0]])),
    }
