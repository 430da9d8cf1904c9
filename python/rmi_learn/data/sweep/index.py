"""The run index of a sweep, ``OUT/index.parquet``: one row per run directory under
``OUT/runs``, derived from the run files and error records only, so it can never disagree
with them (:func:`build_index`)."""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import polars as pl

from rmi_learn.data.runs import (
    ERROR_FILE,
    PARAM_KEYS,
    RUN_FILE,
    atomic_write_bytes,
    read_run_meta,
    run_id,
)
from rmi_learn.data.schema import PHASES
from rmi_learn.data.staging import parquet_bytes
from rmi_learn.data.sweep.configs import is_perturbed

RUNS_SUBDIR = "runs"
INDEX_FILE = "index.parquet"


def _outcome_row(meta: Mapping[str, Any]) -> dict[str, Any]:
    o = dict(meta.get("outcome", {}))
    row: dict[str, Any] = {
        "lift_success": o.pop("lift_success", None),
        "stable_squeeze": o.pop("stable_squeeze", None),
        "failure": o.pop("failure", None),
        "initial_water": o.pop("initial_water", None),
        "final_water": o.pop("final_water", None),
        "wall_s": o.pop("wall_s", None),
    }
    removed = o.pop("water_removed", None) or {}
    for ph in PHASES:
        row[f"water_removed_{ph}"] = removed.get(ph)
    # Any further scalar the engine reports (particle counts, steps, ...), flattened one level.
    for k, v in o.items():
        if isinstance(v, Mapping):
            for k2, v2 in v.items():
                if isinstance(v2, (bool, int, float, str)) or v2 is None:
                    row[f"{k}_{k2}"] = v2
        elif isinstance(v, (bool, int, float, str)) or v is None:
            row[k] = v
    return row


#: The columns every index has, in order, with their types (engine extras follow them).
INDEX_SCHEMA: dict[str, Any] = {
    "run_id": pl.String,
    "status": pl.String,
    "error": pl.String,
    "path": pl.String,
    "size_cm": pl.Int64,
    "porosity": pl.Float64,
    "F_hold": pl.Float64,
    "F_squeeze": pl.Float64,
    "seed": pl.Int64,
    "perturbed": pl.Boolean,
    "lift_success": pl.Boolean,
    "stable_squeeze": pl.Boolean,
    "failure": pl.String,
    "initial_water": pl.Float64,
    "final_water": pl.Float64,
    **{f"water_removed_{ph}": pl.Float64 for ph in PHASES},
    "wall_s": pl.Float64,
    "n_records": pl.Int64,
    "duration_s": pl.Float64,
}


def build_index(out_dir: str | os.PathLike[str], write: bool = True) -> pl.DataFrame:
    """One row per run directory under ``OUT/runs`` (run file or error record), sorted by
    run id, and (if ``write``) stored atomically as ``OUT/index.parquet``.

    Columns: ``run_id``, ``status`` (ok / unstable / failed), ``error``, ``path`` (relative to
    OUT), the parameters ``size_cm, porosity, F_hold, F_squeeze, seed``, ``perturbed`` (the
    run followed seeded force targets from the lift on), ``lift_success``,
    ``stable_squeeze``, ``failure``, ``initial_water`` and ``final_water`` (kg),
    ``water_removed_<phase>`` (kg, null where the phase was not reached), ``wall_s`` (s, the
    engine's figure if it gives one; for runs that shared their prefix, the prefix's time split
    evenly plus the run's own squeeze), ``sweep_wall_s`` (s, measured around the runner; the
    group's time split evenly),
    ``n_records``, ``duration_s`` (simulated s), and any other scalar the outcome holds
    (e.g. particle counts). A run file whose outcome ``failure`` mentions "unstable" has
    status ``unstable``. A write that fails (a full disk) raises its OSError naming the
    index file.
    """
    out = Path(out_dir)
    df = index_frame(out / RUNS_SUBDIR, out)
    if write:
        out.mkdir(parents=True, exist_ok=True)
        data = parquet_bytes(df)
        atomic_write_bytes(out / INDEX_FILE, lambda f: f.write(data))
    return df


def index_frame(root: Path, rel_to: Path) -> pl.DataFrame:
    """The index rows (see :func:`build_index`) of every run directory below ``root``, with
    ``path`` relative to ``rel_to``; an empty frame with the index columns if there is none."""
    rows: list[dict[str, Any]] = []
    seen: set[Path] = set()
    for path in sorted(root.rglob(RUN_FILE)) if root.exists() else []:
        seen.add(path.parent)
        meta = read_run_meta(path)
        stats = (
            pl.scan_parquet(path)
            .select(pl.len().alias("n"), (pl.col("time").max() - pl.col("time").min()).alias("d"))
            .collect()
        )
        orow = _outcome_row(meta)
        failure = orow.get("failure")
        rows.append(
            {
                "run_id": run_id(meta["params"]),
                "status": "unstable" if failure and "unstable" in str(failure).lower() else "ok",
                "error": None,
                "path": path.relative_to(rel_to).as_posix(),
                **{k: meta["params"][k] for k in PARAM_KEYS},
                "perturbed": is_perturbed(meta["config"]),
                **orow,
                "n_records": int(stats["n"][0]),
                "duration_s": float(stats["d"][0]),
            }
        )
    for epath in sorted(root.rglob(ERROR_FILE)) if root.exists() else []:
        if epath.parent in seen:
            continue
        rec = json.loads(epath.read_text())
        params = rec["params"]
        rows.append(
            {
                "run_id": run_id(params),
                "status": rec.get("status", "failed"),
                "error": rec.get("error"),
                "path": epath.relative_to(rel_to).as_posix(),
                **{k: params[k] for k in PARAM_KEYS},
                "perturbed": is_perturbed(rec.get("config", {})),
                "wall_s": rec.get("wall_s"),
            }
        )
    extra = sorted({k for r in rows for k in r} - set(INDEX_SCHEMA))
    columns = list(INDEX_SCHEMA) + extra
    data = {c: [r.get(c) for r in rows] for c in columns}
    return pl.DataFrame(
        {c: pl.Series(c, data[c], dtype=INDEX_SCHEMA.get(c), strict=False) for c in columns}
    ).sort("run_id")
