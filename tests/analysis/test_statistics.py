"""The numbers of ``rmi analyze`` on hand-built indexes with known answers: Student's t, the
squeeze association and its intervals, the lift success table, the water per phase."""

from __future__ import annotations

from typing import Any

import numpy as np
import polars as pl
import pytest

from rmi_learn.analysis.run_table import ANALYSIS_PHASES
from rmi_learn.analysis.statistics import (
    lift_success_table,
    squeeze_association,
    t_critical,
    water_per_phase,
)
from rmi_learn.data.sweep import INDEX_SCHEMA


def _row(
    size: int,
    porosity: float,
    hold: float,
    squeeze: float,
    seed: int = 0,
    *,
    removed_g: float | None = None,
    lift: bool | None = True,
    stable: bool | None = True,
    status: str = "ok",
) -> dict[str, Any]:
    return {
        "run_id": f"size_cm={size}/porosity={porosity}/F_hold={hold}/F_squeeze={squeeze}/"
        f"seed={seed}",
        "status": status,
        "size_cm": size,
        "porosity": porosity,
        "F_hold": hold,
        "F_squeeze": squeeze,
        "seed": seed,
        "lift_success": lift,
        "stable_squeeze": stable,
        # the index stores kg
        "water_removed_squeeze": None if removed_g is None else removed_g / 1e3,
    }


#: The index columns these synthetic rows fill, typed as the sweep's index types them.
_COLUMNS = (
    "run_id",
    "status",
    "size_cm",
    "porosity",
    "F_hold",
    "F_squeeze",
    "seed",
    "lift_success",
    "stable_squeeze",
    "water_removed_squeeze",
)


def _frame(rows: list[dict[str, Any]]) -> pl.DataFrame:
    return pl.DataFrame(rows, schema={c: INDEX_SCHEMA[c] for c in _COLUMNS})


def _association_index(
    slope_g_per_100n: float, rng_seed: int, slope_sd: float = 0.0
) -> pl.DataFrame:
    """Matched groups with a known mean within-group slope (each group's own slope drawn
    with standard deviation ``slope_sd``, g/100 N). Group offsets fall with the group's
    force level, so a pooled (not demeaned) fit would find a negative slope."""
    rng = np.random.default_rng(rng_seed)
    force_sets = [(100.0, 200.0, 300.0), (200.0, 300.0, 400.0), (100.0, 400.0)]
    rows = []
    g = 0
    for size in (8, 10, 12):
        for porosity in (0.5, 0.6, 0.7):
            for hold in (90.0, 150.0, 210.0):
                forces = force_sets[g % len(force_sets)]
                offset = 300.0 - 1.0 * float(np.mean(forces)) + rng.normal(0.0, 20.0)
                slope = slope_g_per_100n + slope_sd * rng.normal()
                for f in forces:
                    y = offset + slope * f / 100.0 + rng.normal(0.0, 2.0)
                    rows.append(_row(size, porosity, hold, f, removed_g=y))
                g += 1
    return _frame(rows)


def _pooled_slope(df: pl.DataFrame) -> float:
    x = df["F_squeeze"].to_numpy()
    y = df["water_removed_squeeze"].to_numpy() * 1e3
    return float(np.polyfit(x, y, 1)[0]) * 100.0


def _naive_se(df: pl.DataFrame) -> float:
    """Run-level (unclustered) OLS standard error of the within-group slope, g/100 N."""
    keys = ["size_cm", "porosity", "F_hold", "seed"]
    d = df.with_columns(
        dx=pl.col("F_squeeze") - pl.col("F_squeeze").mean().over(keys),
        dy=(pl.col("water_removed_squeeze") - pl.col("water_removed_squeeze").mean().over(keys))
        * 1e3,
    )
    dx, dy = d["dx"].to_numpy(), d["dy"].to_numpy()
    b = float(dx @ dy / (dx @ dx))
    n_groups = d.select(keys).n_unique()
    resid = dy - b * dx
    var = float(resid @ resid) / (len(dx) - n_groups - 1) / float(dx @ dx)
    return float(np.sqrt(var)) * 100.0


# ---- statistics on hand-built indexes -------------------------------------------------


@pytest.mark.parametrize(
    ("df", "expected"),
    [(1, 12.7062), (2, 4.3027), (3, 3.1824), (5, 2.5706), (10, 2.2281), (30, 2.0423)],
)
def test_t_critical_matches_tables(df: int, expected: float) -> None:
    assert t_critical(df) == pytest.approx(expected, abs=2e-4)


def test_t_critical_tends_to_normal() -> None:
    assert t_critical(2000) == pytest.approx(1.9612, abs=2e-3)
    with pytest.raises(ValueError):
        t_critical(0)


def test_association_recovers_known_slope_within_groups() -> None:
    index = _association_index(5.0, rng_seed=1)
    assert _pooled_slope(index) < 0  # pooling across groups is confounded by the offsets
    res = squeeze_association(index, n_boot=2000, seed=0)
    assert res["status"] == "ok"
    assert res["n_groups"] == 27 and res["n_runs"] == index.height
    assert res["slope_g_per_100N"] == pytest.approx(5.0, abs=0.7)  # 3 standard errors
    assert res["slope_g_per_N"] == pytest.approx(res["slope_g_per_100N"] / 100.0)
    for ci in (res["ci95_g_per_100N"], res["sandwich"]["ci95_g_per_100N"]):
        lo, hi = ci
        assert lo < 5.0 < hi
        assert lo > 0.0
        assert hi - lo < 2.0
    assert res["ci_method"].startswith("cluster bootstrap")
    assert res["sandwich"]["df"] == 26
    assert set(res["per_size"]) == {"8", "10", "12"}
    for sub in res["per_size"].values():
        assert sub["status"] == "ok" and sub["n_groups"] == 9
        assert sub["ci95_g_per_100N"][0] < 5.0 < sub["ci95_g_per_100N"][1]


def test_association_intervals_have_nominal_coverage() -> None:
    # 40 replicate grids whose groups differ in slope, so residuals are correlated within a
    # group: a 95% interval for the mean slope should miss it about twice, while the naive
    # (run-level) standard error is too small.
    hits = {"bootstrap": 0, "sandwich": 0}
    naive_ratio = []
    for rep in range(40):
        index = _association_index(5.0, rng_seed=100 + rep, slope_sd=3.0)
        res = squeeze_association(index, n_boot=1000)
        naive_ratio.append(_naive_se(index) / res["sandwich"]["se_g_per_100N"])
        for name, ci in (
            ("bootstrap", res["ci95_g_per_100N"]),
            ("sandwich", res["sandwich"]["ci95_g_per_100N"]),
        ):
            hits[name] += int(ci[0] < 5.0 < ci[1])
    assert hits["bootstrap"] >= 34 and hits["sandwich"] >= 34, hits
    assert np.median(naive_ratio) < 0.9


def test_association_bootstrap_is_reproducible() -> None:
    index = _association_index(5.0, rng_seed=2)
    a = squeeze_association(index, n_boot=500, seed=3)
    b = squeeze_association(index, n_boot=500, seed=3)
    assert a["ci95_g_per_100N"] == b["ci95_g_per_100N"]


def test_association_zero_slope_ci_covers_zero() -> None:
    res = squeeze_association(_association_index(0.0, rng_seed=4), n_boot=2000, seed=0)
    assert res["status"] == "ok"
    for lo, hi in (res["ci95_g_per_100N"], res["sandwich"]["ci95_g_per_100N"]):
        assert lo < 0.0 < hi


def test_association_ignores_failed_and_unlifted_runs() -> None:
    index = _association_index(5.0, rng_seed=5)
    clean = squeeze_association(index, n_boot=200, seed=0)
    # Wild values in runs that must not count: a failed run and a lift failure in a
    # matched group, and a lift success with no squeeze removal recorded.
    junk = _frame(
        [
            _row(8, 0.5, 90.0, 350.0, removed_g=1e5, status="failed", lift=None, stable=None),
            _row(8, 0.5, 90.0, 50.0, removed_g=-1e5, lift=False, stable=False),
            _row(8, 0.5, 90.0, 60.0, removed_g=None),
        ]
    )
    res = squeeze_association(pl.concat([index, junk]), n_boot=200, seed=0)
    assert res["slope_g_per_100N"] == pytest.approx(clean["slope_g_per_100N"])
    assert res["n_runs"] == clean["n_runs"]


def test_association_stable_only_drops_lost_grasps() -> None:
    index = _association_index(5.0, rng_seed=6)
    lost = index["F_squeeze"] == 400.0
    index = index.with_columns(stable_squeeze=~lost)
    res = squeeze_association(index, n_boot=200, seed=0, stable_only=True)
    assert res["n_runs"] == index.height - int(lost.sum()) - 9  # groups (100, 400) drop out
    assert 400.0 not in res["F_squeeze_values_N"]


def test_association_null_with_too_few_groups() -> None:
    one_group = _frame(
        [_row(10, 0.6, 150.0, f, removed_g=10.0 + 0.05 * f) for f in (100.0, 200.0, 300.0)]
        + [_row(10, 0.7, 150.0, 200.0, removed_g=12.0)]  # a group with a single force
    )
    res = squeeze_association(one_group, n_boot=100)
    assert res["status"] == "null"
    assert "1 group" in res["reason"]
    assert res["slope_g_per_100N"] is None and res["ci95_g_per_100N"] is None
    assert res["n_groups"] == 1 and res["n_groups_total"] == 2
    empty = squeeze_association(one_group.clear(), n_boot=100)
    assert empty["status"] == "null" and empty["per_size"] == {}


def test_lift_success_table() -> None:
    rows = [
        # 8 cm, porosity 0.7: fails at 90 N, half at 150 N, all at 210 N
        _row(8, 0.7, 90.0, 200.0, lift=False),
        _row(8, 0.7, 90.0, 300.0, lift=False),
        _row(8, 0.7, 150.0, 200.0, lift=True),
        _row(8, 0.7, 150.0, 300.0, lift=False),
        _row(8, 0.7, 210.0, 200.0, lift=True),
        _row(8, 0.7, 210.0, 300.0, seed=1, lift=True),
        # 8 cm, porosity 0.5: only 90 N was run
        _row(8, 0.5, 90.0, 200.0, lift=True),
        # 10 cm, porosity 0.7: never lifts; a failed run is not counted
        _row(10, 0.7, 210.0, 200.0, lift=False),
        _row(10, 0.7, 150.0, 200.0, status="failed", lift=None, stable=None),
    ]
    table = lift_success_table(_frame(rows))
    assert table["sizes_cm"] == [8, 10]
    assert table["porosities"] == [0.5, 0.7]
    assert table["F_hold_values"] == [90.0, 150.0, 210.0]
    cells = {(c["size_cm"], c["porosity"], c["F_hold"]): c for c in table["cells"]}
    assert cells[(8, 0.7, 90.0)]["rate"] == 0.0
    assert cells[(8, 0.7, 150.0)]["rate"] == 0.5 and cells[(8, 0.7, 150.0)]["n"] == 2
    assert cells[(8, 0.7, 210.0)]["rate"] == 1.0
    assert (8, 0.5, 150.0) not in cells  # missing cell: no run there
    assert (10, 0.7, 150.0) not in cells  # its only run failed
    by = {(r["size_cm"], r["porosity"]): r for r in table["by_size_porosity"]}
    assert by[(8, 0.7)]["rate"] == pytest.approx(3 / 6)
    assert by[(8, 0.7)]["min_F_hold_any_success"] == 150.0
    assert by[(8, 0.7)]["min_F_hold_all_success"] == 210.0
    assert by[(8, 0.5)]["min_F_hold_any_success"] == 90.0
    assert by[(10, 0.7)]["min_F_hold_any_success"] is None
    assert by[(10, 0.7)]["min_F_hold_all_success"] is None


def test_water_per_phase_keeps_negative_values_and_skips_unreached_phases() -> None:
    phases = ANALYSIS_PHASES
    base = {f"water_removed_{ph}": 0.010 for ph in phases}  # 10 g each
    rows = []
    for k in range(4):
        r = dict(base, run_id=f"r{k}", status="ok", size_cm=10)
        r["water_removed_lift"] = -0.002 * (k + 1)  # water taken back up during the lift
        r.update({f"reached_{ph}": True for ph in phases})
        rows.append(r)
    # A lift failure: the engine stores 0 kg for the phases it never reached.
    unreached = dict(base, run_id="r4", status="ok", size_cm=10)
    unreached.update(water_removed_waiting=0.0, water_removed_squeeze=0.0)
    unreached.update({f"reached_{ph}": ph not in ("waiting", "squeeze") for ph in phases})
    rows.append(unreached)
    failed = {"run_id": "r5", "status": "failed", "size_cm": 10}
    rows.append(failed)
    res = water_per_phase(pl.DataFrame(rows, infer_schema_length=None))
    lift = res["per_phase"]["lift"]
    assert lift["n"] == 5 and lift["n_negative"] == 4
    assert lift["min"] == pytest.approx(-8.0)
    assert res["per_phase"]["squeeze"]["n"] == 4
    assert res["per_phase"]["squeeze"]["median"] == pytest.approx(10.0)
    assert res["n_runs_all_phases"] == 4
    pooled = res["pooled_fraction"]
    assert sum(pooled.values()) == pytest.approx(1.0)
    assert pooled["lift"] < 0  # negative shares are reported, not clipped
    # Per run: lift -2k g against 50 g in the other five phases.
    expected = np.median([-2.0 * k / (50.0 - 2.0 * k) for k in (1, 2, 3, 4)])
    assert res["median_fraction"]["lift"] == pytest.approx(expected)
