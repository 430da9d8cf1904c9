"""Goal options and the reachable default goal of rmi_learn.sim.goal."""

from __future__ import annotations

import pytest

import rmi_sph
from rmi_learn.data.schema import PHASES
from rmi_learn.sim.goal import goal_mass, reachable_goal, reference_release, unit_fraction
from tiny_trial import tiny_config


def test_checks_name_the_option() -> None:
    assert goal_mass(0.25) == 0.25 and unit_fraction("x", 1) == 1.0
    for bad in (-1e-6, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="goal must be"):
            goal_mass(bad)
    with pytest.raises(ValueError, match="release_fraction must be in"):
        unit_fraction("release_fraction", 1.01)


def test_reachable_goal_is_handover_water_less_part_of_the_release() -> None:
    assert reachable_goal(0.8, 0.06, 0.5) == pytest.approx(0.77)
    assert reachable_goal(0.01, 0.06, 1.0) == 0.0  # never below empty


def test_reference_release_runs_the_trial_to_its_end() -> None:
    trial = rmi_sph.Trial(tiny_config(), num_threads=1)
    while PHASES.index(trial.phase) < PHASES.index("lift"):
        trial.step(1)
    water = float(trial.observation()["M_L"])
    release = reference_release(trial, 300.0, substeps=10)
    assert trial.finished and trial.failure is None
    assert 0.0 < release < water
    assert release >= water - float(trial.observation()["M_L"])  # the most, not the last
