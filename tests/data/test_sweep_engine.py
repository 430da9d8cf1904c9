"""The sweep with the real engine (not a test double): the `tiny` preset end to end."""

from __future__ import annotations

import math
from pathlib import Path

import polars as pl
import pytest

from rmi_learn.data import schema
from rmi_learn.data.runs import read_run
from rmi_learn.data.sweep import expand_grid, load_grid, run_sweep


def test_tiny_preset_runs_with_the_engine_and_resumes(tmp_path: Path) -> None:
    grid = load_grid("tiny")
    specs = expand_grid(grid)
    out = tmp_path / "grid"
    res = run_sweep(specs, out, workers=2, threads_per_run=1, progress=False, grid=grid)
    assert res.ok == len(specs) and res.failed == 0
    index = pl.read_parquet(out / "index.parquet")
    assert index.height == len(specs)
    assert index["status"].to_list() == ["ok"] * len(specs)
    for path in index["path"].to_list():
        frame, meta = read_run(out / path if not Path(path).is_absolute() else path)
        assert set(frame.columns) == set(schema.EXTRAS) | set(schema.OBS) | set(schema.ACTIONS)
        total = (frame["M_L"] + frame["M_expelled"]).to_numpy()
        assert all(math.isclose(x, total[0], rel_tol=0, abs_tol=1e-12) for x in total)
        assert meta["outcome"]["initial_water"] > 0
    # A second sweep over the same directory does nothing and loses nothing.
    again = run_sweep(specs, out, workers=2, threads_per_run=1, progress=False, grid=grid)
    assert again.ok == 0 and again.skipped == len(specs)
    # The README's polars query over the grid.
    q = (
        pl.scan_parquet(out / "index.parquet")
        .filter(pl.col("status") == "ok")
        .group_by("porosity", "F_hold")
        .agg(pl.col("lift_success").mean())
        .collect()
    )
    assert q.height == len({(s.params["porosity"], s.params["F_hold"]) for s in specs})


def test_a_grid_the_engine_refuses_fails_before_any_run(tmp_path: Path) -> None:
    # An override out of range would fail every run one by one; it is found up front,
    # naming a run and the field, and nothing is written.
    grid = {**load_grid("tiny"), "overrides": {"dt": -1.0}}
    out = tmp_path / "grid"
    with pytest.raises(ValueError, match=r"run size_cm=8/.*`dt` = -1.*no run was started"):
        run_sweep(expand_grid(grid), out, workers=0, progress=False, grid=grid)
    assert not out.exists()
