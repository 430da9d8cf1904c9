"""studies/resolution.py: water removed per phase against the particle radius."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import polars as pl
import pytest
from study_scripts import load_study

PHASES = ("ramp", "hold", "lift", "waiting", "squeeze")


def _sweep(root: Path, name: str, radius: float, rows: list[dict[str, Any]]) -> Path:
    d = root / name
    d.mkdir()
    (d / "grid.json").write_text(json.dumps({"radius_m": radius}))
    full = []
    for r in rows:
        row = {"status": "ok", "size_cm": 8, "porosity": 0.7, "F_hold": 140.0, "F_squeeze": 150.0}
        row |= {"seed": 0, "initial_water": 0.8}
        row |= {f"water_removed_{p}": 0.0 for p in PHASES}
        full.append(row | r)
    pl.DataFrame(full).write_parquet(d / "index.parquet")
    return d


def test_rows_per_condition_coarse_to_fine(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    m = load_study("resolution")
    fine = _sweep(
        tmp_path,
        "fine",
        0.004,
        [{"water_removed_hold": 0.010, "water_removed_squeeze": 0.006}],
    )
    coarse = _sweep(
        tmp_path,
        "coarse",
        0.008,
        [
            {"water_removed_hold": 0.050, "water_removed_lift": None, "initial_water": 0.82},
            {"seed": 1, "water_removed_hold": 0.040},
            # A run that did not finish is not a data point.
            {"seed": 2, "status": "failed", "water_removed_hold": 0.5},
        ],
    )
    res = m.load([fine, coarse])
    rows = res[(8, 0.7, 140.0, 150.0, 0)]
    assert [r["radius_mm"] for r in rows] == [8.0, 4.0]
    assert rows[0]["removed_g"]["hold"] == pytest.approx(50.0)
    assert rows[0]["removed_g"]["lift"] == 0.0
    assert rows[0]["total_pct"] == pytest.approx(100 * 50 / 820)
    assert rows[1]["total_g"] == pytest.approx(16.0)
    assert set(res) == {(8, 0.7, 140.0, 150.0, 0), (8, 0.7, 140.0, 150.0, 1)}
    assert m.main([str(fine), str(coarse)]) == 0
    assert "16.0 (2 %)" in capsys.readouterr().out
    with pytest.raises(ValueError, match="same radius"):
        m.load([fine, _sweep(tmp_path, "again", 0.004, [{}])])
    assert m.main([str(tmp_path / "nothing")]) == 2
    assert "not a finished sweep" in capsys.readouterr().err


def test_committed_grids_load_and_the_series_varies_only_the_radius() -> None:
    from rmi_learn.data.sweep import load_grid

    grids = Path(__file__).resolve().parents[2] / "studies" / "grids"
    for f in sorted(grids.rglob("*.json")):
        load_grid(path=f)
    series = [load_grid(path=f) for f in sorted((grids / "resolution").glob("*.json"))]
    radii = sorted(g["radius_m"] for g in series)
    assert radii == [0.004, 0.005, 0.0065, 0.008]
    drop = ("name", "description", "radius_m")
    rest = [{k: v for k, v in g.items() if k not in drop} for g in series]
    assert all(r == rest[0] for r in rest)
    assert "dt" not in rest[0]["overrides"]
