"""studies/convergence.py: a trial's observables against particle radius and time step."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from study_scripts import load_study

PHASES = ("ramp", "hold", "lift", "waiting", "squeeze")


def _record(
    radius_mm: float, squeeze_g: float, *, dt: float = 0.001, peak: float = 300.0, **kw: Any
) -> dict[str, Any]:
    removed = {p: 0.0 for p in PHASES} | {"ramp": 10.0, "squeeze": squeeze_g}
    rec = {
        "size_cm": 8,
        "dt_s": dt,
        "radius_mm": radius_mm,
        "status": "ok",
        "removed_g": removed,
        "total_g": sum(removed.values()),
        "peak_force_N": peak,
        "lift_success": True,
        "particles": int(1e4 / radius_mm**3),
        "wall_s": 1.0,
        "initial_g": 700.0,
    }
    return rec | kw


def test_coarsest_radius_whose_finer_neighbours_all_pass() -> None:
    m = load_study("convergence")
    # Finest total 40 g: 5 % is 2 g. 6.5 mm is within it, 8 mm is not.
    recs = [_record(4.0, 30.0), _record(5.0, 29.0), _record(6.5, 31.5), _record(8.0, 20.0)]
    (series,) = m.converge(recs, 0.05)
    assert series["converged_radius_mm"] == 6.5
    assert [r["radius_mm"] for r in series["rows"]] == [4.0, 5.0, 6.5, 8.0]
    assert [r["passes"] for r in series["rows"]] == [True, True, True, False]
    assert series["rows"][3]["deviation"]["total"] == pytest.approx(-10.0 / 40.0)


def test_a_failing_middle_radius_stops_the_chain() -> None:
    m = load_study("convergence")
    # 5 mm is off by 5 g; 6.5 mm agrees again by chance but is not counted as converged.
    recs = [_record(4.0, 30.0), _record(5.0, 25.0), _record(6.5, 30.5)]
    (series,) = m.converge(recs, 0.05)
    assert series["converged_radius_mm"] is None
    assert series["rows"][2]["passes"]


def test_peak_force_and_lift_take_part() -> None:
    m = load_study("convergence")
    recs = [_record(4.0, 30.0), _record(5.0, 30.0, peak=330.0), _record(6.5, 30.0)]
    (series,) = m.converge(recs, 0.05)
    assert not series["rows"][1]["passes"]
    recs = [_record(4.0, 30.0), _record(5.0, 30.0, lift_success=False)]
    assert m.converge(recs, 0.05)[0]["converged_radius_mm"] is None


def test_series_split_by_size_and_dt_and_unstable_rows_kept() -> None:
    m = load_study("convergence")
    recs = [
        _record(4.0, 30.0),
        _record(5.0, 30.0),
        _record(4.0, 30.0, dt=0.002),
        {"size_cm": 8, "dt_s": 0.002, "radius_mm": 5.0, "status": "unstable", "error": "diverged"},
    ]
    table = m.converge(recs, 0.05)
    assert [(s["size_cm"], s["dt_s"]) for s in table] == [(8, 0.001), (8, 0.002)]
    assert table[0]["converged_radius_mm"] == 5.0
    assert table[1]["converged_radius_mm"] is None
    assert table[1]["rows"][1] == {"radius_mm": 5.0, "status": "unstable", "passes": False}


def test_observables_from_a_trial_result() -> None:
    m = load_study("convergence")
    outcome = {
        "water_removed": {"settle": 0.001, "ramp": 0.012, "squeeze": 0.0275},
        "initial_water": 0.65,
        "lift_success": True,
        "failure": None,
        "steps": 100,
        "n_fluid": 10,
        "n_solid": 20,
    }
    obs = m.observables(outcome, {"F_meas": [0.0, 120.0, float("nan"), 301.5]})
    assert obs["removed_g"]["ramp"] == pytest.approx(12.0)
    assert obs["removed_g"]["hold"] == 0.0
    # Settling is before the grasp: not one of the observables.
    assert obs["total_g"] == pytest.approx(39.5)
    assert obs["peak_force_N"] == 301.5
    assert obs["particles"] == 30


def test_timings_of_a_grid_preset_without_its_dt() -> None:
    m = load_study("convergence")
    t = m.timings("study")
    assert "dt" not in t and t["squeeze_hold_time"] == 1.5
    with pytest.raises(ValueError, match="--timings"):
        m.timings("nonexistent")


def test_table_cli_reads_a_series_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    m = load_study("convergence")
    for rec in (_record(4.0, 30.0), _record(5.0, 30.5)):
        (tmp_path / f"{m.trial_name(8, rec['radius_mm'], 0.001)}.json").write_text(json.dumps(rec))
    assert m.main(["table", str(tmp_path)]) == 0
    assert "converged from r = 5 mm" in capsys.readouterr().out
    assert m.main(["table", str(tmp_path), "--tolerance", "1.5"]) == 2
    assert "--tolerance" in capsys.readouterr().err
    assert m.main(["run", "--out", str(tmp_path), "--radii", "0.1"]) == 2


def test_controller_times_are_held_across_time_steps() -> None:
    m = load_study("convergence")
    job = {
        "size_cm": 8,
        "porosity": 0.6,
        "hold_N": 100.0,
        "squeeze_N": 300.0,
        "radius_mm": 8.0,
        "seed": 0,
        "timings": {},
    }
    as_configured = m.config_of({**job, "dt_s": 0.002})
    same = m.config_of({**job, "dt_s": 0.002, "controller_dt_s": 0.002})
    assert same == as_configured
    fine = m.config_of({**job, "dt_s": 0.001, "controller_dt_s": 0.002})
    for section, field in m.STEP_COUNTS:
        assert fine[section][field] == 2 * as_configured[section][field], field
    # The filter's decay over 2 ms: one step of the configured eta, two of the rescaled one.
    eta, eta_fine = as_configured["gate"]["eta_f"], fine["gate"]["eta_f"]
    assert (1.0 - eta_fine) ** 2 == pytest.approx(1.0 - eta, rel=1e-12)
    coarse = m.config_of({**job, "dt_s": 0.008, "controller_dt_s": 0.002})
    assert coarse["controller"]["k_contact"] == max(
        1, round(as_configured["controller"]["k_contact"] / 4)
    )
    import rmi_sph

    rmi_sph.validate_config(fine)


def test_a_controller_dt_out_of_range_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    m = load_study("convergence")
    assert m.main(["run", "--out", "/nonexistent/x", "--controller-dt", "0"]) != 0
    assert "--controller-dt" in capsys.readouterr().err
