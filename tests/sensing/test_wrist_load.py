"""The wrist load the engine records (``W_x, W_y, W_z``: the force of the sponge and its
water on both pads): it weighs what the pads carry, vanishes before the grasp, and the
noiseless sensor mode reports the engine's own values."""

from __future__ import annotations

import numpy as np
import pytest

import rmi_sph
from rmi_learn.sensing import (
    SENSOR_NAMES,
    STANDARD_GRAVITY,
    SensorModel,
    dry_mass,
    observe_rows,
    weight_estimate,
)
from rmi_learn.sim.replay import control_substeps
from tiny_trial import tiny_config


@pytest.fixture(scope="module")
def lifted() -> dict:
    """The tiny trial's records every control step, and what it carries in its squeeze."""
    sim = rmi_sph.Trial(tiny_config(), num_threads=1)
    n = control_substeps(float(sim.dt))
    recs = [sim.take_record()]
    while not sim.finished:
        sim.step(n)
        recs.append(sim.take_record())
    solid, fluid = sim.particles("solid"), sim.particles("fluid")
    # Water that dripped off lies below the sponge's lowest skeleton particle.
    above = fluid["positions"][:, 2] >= solid["positions"][:, 2].min() - 0.01
    return {
        "recs": recs,
        "m_dry": dry_mass(sim),
        "carried_water": float(fluid["mass"][above].sum()),
    }


def test_carried_in_the_air_the_wrist_load_weighs_the_sponge_and_its_water(lifted: dict) -> None:
    squeeze = [r for r in lifted["recs"] if r["phase"] == "squeeze"]
    assert len(squeeze) >= 5
    carried = -np.mean([r["W_z"] for r in squeeze]) / STANDARD_GRAVITY
    want = lifted["m_dry"] + lifted["carried_water"]
    assert carried == pytest.approx(want, rel=0.015)
    # The weight estimate counts the expelled water still on the sponge: above M_L.
    est = weight_estimate(squeeze[-1]["W_z"], lifted["m_dry"])
    assert est > squeeze[-1]["M_L"]
    lateral = max(abs(np.mean([r[k] for r in squeeze])) for k in ("W_x", "W_y"))
    assert lateral < 0.02 * abs(np.mean([r["W_z"] for r in squeeze]))


def test_before_the_grasp_the_pads_carry_next_to_nothing(lifted: dict) -> None:
    # Only the water beside the open pads touches them: below a gram's weight.
    settle = [r for r in lifted["recs"] if r["phase"] == "settle"]
    assert settle and all(abs(r[k]) < 0.01 for r in settle for k in ("W_x", "W_y", "W_z"))


def test_noiseless_sensors_report_the_engines_loads_width_and_wrist_load(lifted: dict) -> None:
    rows = np.array([[r[n] for n in SENSOR_NAMES] for r in lifted["recs"]])
    out = observe_rows(rows, SensorModel.noiseless(), (0,))
    for name in ("w", "F_L", "F_R", "F_meas", "W_x", "W_y", "W_z"):
        i = SENSOR_NAMES.index(name)
        assert np.array_equal(out[:, i], [r[name] for r in lifted["recs"]]), name


def test_the_wrist_load_is_bit_identical_for_one_and_two_threads() -> None:
    cols = [rmi_sph.run_trial(tiny_config(), num_threads=t)["columns"] for t in (1, 2)]
    for k in ("W_x", "W_y", "W_z"):
        assert np.array_equal(cols[0][k], cols[1][k])
