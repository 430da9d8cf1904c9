"""Release probes and the settle-predicting estimator (control_bench.feedback.release): the
probe plan spans the setpoint bounds, a probe's target is the weight estimate at the release
minus the water left in the pores after the settle, probes are bit-identical for one and two
engine threads, a fold's fit never sees its own group, and the protocol checks the probes'
fields."""

from __future__ import annotations

import copy
import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

import rmi_sph
from rmi_learn.control_bench.feedback.episode import Plant
from rmi_learn.control_bench.feedback.estimators import WINDOW, WZ_INDEX, Ridge
from rmi_learn.control_bench.feedback.laws import Fixed
from rmi_learn.control_bench.feedback.protocol import PROTOCOL_DIR, validate
from rmi_learn.control_bench.feedback.release import (
    SettleEstimate,
    fit_settle,
    probe_plan,
    probe_rows,
    release_features,
)
from rmi_learn.control_bench.feedback.start_states import Snapshot
from rmi_learn.control_bench.feedback.worker import StateWork
from rmi_learn.errors import InputError
from rmi_learn.sensing import STANDARD_GRAVITY, SensorModel, dry_mass
from rmi_learn.sim.replay import control_substeps
from tiny_trial import records_until, tiny_config

PROTOCOL: dict[str, Any] = {
    "horizon": 8,
    "settle_ticks": 4,
    "release_probes": {"setpoints": 2, "ticks": [3, 8], "penalty": 0.01},
}


@dataclass
class _Run:
    run_id: str = "r0"
    size_cm: int = 8
    porosity: float = 0.8
    F_hold: float = 20.0
    F_squeeze: float = 150.0
    seed: int = 0


@dataclass
class _Job:
    protocol: dict[str, Any]
    sensors: SensorModel
    run: _Run


def _work(threads: int, sensors: SensorModel) -> StateWork:
    """The tiny trial in its squeeze, as a tuning state of a worker."""
    sim = rmi_sph.Trial(tiny_config(), num_threads=threads)
    n = control_substeps(float(sim.dt))
    recs = records_until(sim, "squeeze", n)
    snap = Snapshot(len(recs) - 1, sim.get_state(), recs[-(WINDOW + 1) :], [])
    plant = Plant(sim, n, 16.0, 400.0, 20.0)
    return StateWork(_Job(PROTOCOL, sensors, _Run()), plant, snap, dry_mass(sim))  # type: ignore[arg-type]


def test_the_plan_spans_the_bounds_and_releases_after_each_listed_step() -> None:
    plan = probe_plan({"release_probes": {"setpoints": 3, "ticks": [4, 8]}}, 16.0, 400.0)
    assert plan == [(16.0, 4), (16.0, 8), (208.0, 4), (208.0, 8), (400.0, 4), (400.0, 8)]


def test_a_probe_targets_the_weight_at_the_release_minus_the_settled_water() -> None:
    work = _work(1, SensorModel.noiseless())
    rows = probe_rows(work)
    assert [(r["setpoint_N"], r["release_tick"]) for r in rows] == [
        (16.0, 3),
        (16.0, 8),
        (400.0, 3),
        (400.0, 8),
    ]
    assert all(r["status"] == "ok" and np.all(np.isfinite(r["features"])) for r in rows)
    assert all(r["features"][-1] == 20.0 for r in rows)  # the grip the pads return to
    # Executed again by hand: with exact sensors the target is -W_z/g - m_dry - M_L(settle).
    e = work.run(Fixed([400.0]), True, True, 0, horizon=8, keep_seen=True)
    w_z = float(e.seen[-1].observed[WZ_INDEX])
    expected = -w_z / STANDARD_GRAVITY - work.m_dry - e.M_L_settle
    assert rows[3]["target_kg"] == pytest.approx(expected, rel=1e-12, abs=1e-15)
    assert e.seen[-1].record["M_L"] == e.M_L_reach
    # Pressing harder leaves less water to come back into the pores.
    assert rows[3]["target_kg"] > rows[1]["target_kg"]


def test_probes_are_bit_identical_for_one_and_two_threads() -> None:
    one = probe_rows(_work(1, SensorModel()))
    two = probe_rows(_work(2, SensorModel()))
    assert one == two


def _rows(fold: str, target: float, n: int = 6) -> list[dict[str, Any]]:
    rng = np.random.default_rng(len(fold))
    return [
        {
            "size_cm": 8,
            "fold": fold,
            "target_kg": target + 0.001 * i,
            "features": rng.normal(size=4).tolist(),
        }
        for i in range(n)
    ]


def test_a_folds_fit_never_sees_its_own_group() -> None:
    rows = _rows("a", 0.01) + _rows("b", 0.02) + _rows("c", 0.03)
    fit = fit_settle(rows, 8, "a", 0.01)
    assert fit is not None and fit.report["probes"] == 12
    assert set(fit.report["settle_left_out_rms_kg"]) == {"b", "c"}
    poisoned = [{**r, "target_kg": 1e3} if r["fold"] == "a" else r for r in rows]
    again = fit_settle(poisoned, 8, "a", 0.01)
    assert again is not None
    x = np.array(rows[0]["features"])
    assert again.model.predict(x) == fit.model.predict(x)
    failed = [{**r, "target_kg": None} for r in rows if r["fold"] != "a"]
    assert fit_settle(failed, 8, "a", 0.01) is None


def test_the_settle_estimate_is_the_weight_minus_the_predicted_water_outside() -> None:
    work = _work(1, SensorModel.noiseless())
    e = work.run(Fixed([200.0]), True, False, 0, horizon=4, keep_seen=True)
    x = release_features(e.seen, work.m_dry, 20.0)
    model = Ridge(np.zeros(x.size), np.ones(x.size), np.eye(x.size)[-1] * 1e-4, 0.002, 1.0)
    est = SettleEstimate(model, work.m_dry, 20.0)
    w_z = float(e.seen[-1].observed[WZ_INDEX])
    expected = -w_z / STANDARD_GRAVITY - work.m_dry - (0.002 + 1e-4 * 20.0)
    assert est(e.seen) == pytest.approx(expected, rel=1e-12)


@pytest.fixture
def raw() -> dict[str, Any]:
    return json.loads((PROTOCOL_DIR / "control.json").read_text())


def test_the_control_protocol_lists_the_settle_loop_with_its_probes(raw: dict) -> None:
    p = validate(raw)
    assert "pi-settle" in p["controllers"] and max(p["release_probes"]["ticks"]) <= p["horizon"]


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda r: r.pop("release_probes"), "release_probes must be an object"),
        (lambda r: r["release_probes"].update(setpoints=1), r"setpoints must be an integer in"),
        (lambda r: r["release_probes"].update(ticks=[8, 33]), r"ticks must be .* \[1, 32\]"),
        (lambda r: r["release_probes"].update(penalty=0), r"penalty must be a number in"),
        (lambda r: r.update(tasks=["reach"]), "pi-settle needs the settle task"),
    ],
)
def test_bad_probe_fields_are_one_line_naming_them(raw: dict, edit: Any, message: str) -> None:
    bad = copy.deepcopy(raw)
    edit(bad)
    with pytest.raises(InputError, match=message):
        validate(bad)
