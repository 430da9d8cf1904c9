"""studies/pore_balance.py: water released against pore volume closed, per phase."""

from __future__ import annotations

import math

import pytest
from study_scripts import load_study

#: (phase, M_L kg, V_pore m^3) samples of a short made-up trial.
SAMPLES = [
    ("settle", 0.800, 800e-6),
    ("close", 0.800, 806e-6),
    ("ramp", 0.800, 806e-6),
    ("ramp", 0.780, 796e-6),
    ("hold", 0.775, 796e-6),
    ("hold", 0.760, 797e-6),
    ("done", 0.760, 796e-6),
]


def test_per_phase_first_and_last_sample() -> None:
    m = load_study("pore_balance")
    rows = m.per_phase(SAMPLES)
    assert [r["phase"] for r in rows] == ["settle", "close", "ramp", "hold", "done"]
    ramp = rows[2]
    assert ramp["water_g"] == pytest.approx((800.0, 780.0))
    assert ramp["released_g"] == pytest.approx(20.0)
    assert ramp["closed_cm3"] == pytest.approx(10.0)
    # The hold reopens 1 cm^3: closed is negative, not clipped.
    assert rows[3]["closed_cm3"] == pytest.approx(-1.0)


def test_balance_counts_from_the_plates_closing() -> None:
    m = load_study("pore_balance")
    b = m.balance(SAMPLES)
    # From close (800 g, 806 cm^3) to the end (760 g, 796 cm^3): 40 g for 10 g of pores.
    assert b["released_g"] == pytest.approx(40.0)
    assert b["closed_cm3"] == pytest.approx(10.0)
    assert b["ratio"] == pytest.approx(4.0)
    # From the start instead: the settle's 800 cm^3 is the reference.
    assert m.balance(SAMPLES, since="settle")["closed_cm3"] == pytest.approx(4.0)
    # No pore volume closed: the ratio is infinite, not a division error.
    flat = [("close", 0.8, 800e-6), ("done", 0.79, 800e-6)]
    assert math.isinf(m.balance(flat)["ratio"])
    with pytest.raises(ValueError, match="close"):
        m.balance([("settle", 0.8, 800e-6)])


def test_bad_options_are_clear_errors(capsys: pytest.CaptureFixture[str]) -> None:
    m = load_study("pore_balance")
    assert m.main(["--radius", "0.008", "--every", "0"]) == 2
    assert "--every" in capsys.readouterr().err
    assert m.main(["--radius", "0.5"]) == 2
    assert "particle_radius" in capsys.readouterr().err
    # The gap reaches the engine's gripper config, whose range check names it.
    assert m.main(["--radius", "0.008", "--gap", "0.5"]) == 2
    assert "gripper.gap" in capsys.readouterr().err


def test_layer_saturation_groups_by_rest_x() -> None:
    m = load_study("pore_balance")
    # Two layers (x = -0.01 and 0.01, the second with round-off), unordered input.
    rest_x = [0.01, -0.01, 0.0100000001, -0.01]
    sat = [0.4, 1.0, 0.6, 0.8]
    layers = m.layer_saturation(rest_x, sat)
    assert [x for x, _ in layers] == pytest.approx([-0.01, 0.01])
    assert [s for _, s in layers] == pytest.approx([0.9, 0.5])
