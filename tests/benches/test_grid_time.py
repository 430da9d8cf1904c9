"""benches/grid_time.py: a grid's wall time on N workers from a sample sweep's trial times."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import polars as pl
import pytest


def test_makespan_longest_first(bench_script: Callable[[str], Any]) -> None:
    m = bench_script("grid_time")
    # Longest first, not the optimum (6 = 3 + 3 | 2 + 2 + 2): what a pool of workers does.
    assert m.makespan([3.0, 3.0, 2.0, 2.0, 2.0], 2) == 7.0
    assert m.makespan([5.0, 1.0, 1.0], 4) == 5.0
    assert m.makespan([1.0] * 10, 1) == 10.0
    with pytest.raises(ValueError):
        m.makespan([1.0], 0)


def _sample(tmp_path: Path) -> Path:
    rows = [
        {"size_cm": 8, "status": "ok", "wall_s": 50.0, "lift_success": True},
        {"size_cm": 8, "status": "ok", "wall_s": 70.0, "lift_success": True},
        {"size_cm": 10, "status": "ok", "wall_s": 100.0, "lift_success": True},
        {"size_cm": 12, "status": "ok", "wall_s": 200.0, "lift_success": True},
        {"size_cm": 12, "status": "ok", "wall_s": 100.0, "lift_success": False},
        {"size_cm": 12, "status": "failed", "wall_s": 1.0, "lift_success": None},
    ]
    pl.DataFrame(rows).write_parquet(tmp_path / "index.parquet")
    return tmp_path


def test_mean_time_per_size_and_the_lifted_only_bound(
    tmp_path: Path, bench_script: Callable[[str], Any]
) -> None:
    m = bench_script("grid_time")
    idx = _sample(tmp_path) / "index.parquet"
    assert m.mean_time_by_size(idx) == {8: 60.0, 10: 100.0, 12: 150.0}
    assert m.mean_time_by_size(idx, lifted_only=True)[12] == 200.0


def test_cli_extrapolates_the_paper_grid(
    tmp_path: Path, bench_script: Callable[[str], Any], capsys: pytest.CaptureFixture[str]
) -> None:
    m = bench_script("grid_time")
    sample = _sample(tmp_path)
    assert m.main([str(sample), "--grid", "paper", "--workers", "1", "2", "--json"]) == 0
    import json

    res = json.loads(capsys.readouterr().out)
    # 198 runs per size of the paper grid: (60 + 100 + 150) s each, in 99 jobs of the six
    # squeeze forces that share a prefix.
    assert (res["runs"], res["jobs"]) == (594, 99)
    assert res["cpu_hours"] == pytest.approx(198 * 310.0 / 3600.0)
    assert res["wall"][1]["wall_h"] == pytest.approx(res["cpu_hours"] / 2, rel=0.01)
    assert m.main([str(tmp_path / "missing")]) == 2
    assert "not a finished sweep" in capsys.readouterr().err
