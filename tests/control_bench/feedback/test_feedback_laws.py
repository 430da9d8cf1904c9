"""Closed loops executed tick by tick (control_bench.feedback.episode and .laws): PI on the
simulator's M_L reaches a goal that constant grips bracket, every law sees only its mode's
channels, and an episode is bit-identical for one and two engine threads."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import rmi_sph
from rmi_learn.control_bench.feedback.episode import Plant, Tick, run_episode
from rmi_learn.control_bench.feedback.estimators import PrivilegedEstimate, WeightEstimate
from rmi_learn.control_bench.feedback.laws import PI, Fixed, Hold
from rmi_learn.sensing import SensorModel, dry_mass
from rmi_learn.sim.replay import control_substeps
from tiny_trial import records_until, tiny_config

H = 16


def _start(threads: int) -> tuple[Plant, bytes, list[dict[str, Any]], float]:
    """The tiny trial in its squeeze (lifted), with the records of the steps before."""
    sim = rmi_sph.Trial(tiny_config(), num_threads=threads)
    n = control_substeps(float(sim.dt))
    recs = records_until(sim, "squeeze", n)
    return Plant(sim, n, 16.0, 400.0, 20.0), sim.get_state(), recs[-8:], dry_mass(sim)


@pytest.fixture(scope="module")
def start() -> tuple[Plant, bytes, list[dict[str, Any]], float]:
    return _start(1)


def _run(start: Any, law: Any, sensors: SensorModel | None = None, settle: int = 0) -> Any:
    plant, state, hist, _ = start
    return run_episode(plant, state, hist, law, H, settle, sensors, (1, 2))


def test_pi_on_the_simulators_water_reaches_a_goal_constant_grips_bracket(start: Any) -> None:
    lo, hi = _run(start, Fixed([16.0])), _run(start, Fixed([400.0]))
    assert lo.status == hi.status == "ok" and hi.M_L_reach < lo.M_L_reach - 1e-3
    goal = 0.5 * (lo.M_L_reach + hi.M_L_reach)
    pi = _run(start, PI(PrivilegedEstimate(), goal, 80000.0, 0.0, 16.0, 400.0))
    assert pi.status == "ok"
    assert abs(pi.M_L_reach - goal) < 0.1 * abs(lo.M_L_reach - goal)
    assert all(16.0 <= f <= 400.0 for f in pi.forces)


def test_hold_keeps_the_start_setpoint_and_fixed_plays_its_sequence(start: Any) -> None:
    applied = start[2][-1]["F_target"]
    assert _run(start, Hold()).forces == [applied] * H
    seq = [30.0, 60.0, 90.0]
    assert _run(start, Fixed(seq)).forces == seq + [90.0] * (H - 3)


def test_the_settle_returns_the_pads_to_the_holding_force(start: Any) -> None:
    e = _run(start, Fixed([300.0]), settle=5)
    assert e.forces == [300.0] * H + [20.0] * 5 and e.M_L_settle is not None


def test_a_sensor_mode_law_never_reads_the_simulators_water(start: Any) -> None:
    seen: list[Tick] = []

    class Spy:
        def start(self, history: list[Tick]) -> None:
            seen.extend(history)

        def act(self, tick: Tick) -> float:
            seen.append(tick)
            return 100.0

    _run(start, Spy(), SensorModel())
    assert all(t.observed is not None and t.observed.shape == (16,) for t in seen)
    est = WeightEstimate(start[3], 0.0)
    t = seen[-1]
    fake = Tick({**t.record, "M_L": -1.0}, t.observed, t.applied)
    assert est([fake]) == est([t])


def test_an_episode_with_noise_is_bit_identical_for_one_and_two_threads(start: Any) -> None:
    law = lambda: PI(WeightEstimate(start[3], 0.03), 0.8, 150000.0, 0.0, 16.0, 400.0)  # noqa: E731
    one = _run(start, law(), SensorModel(), settle=3)
    two = _run(_start(2), law(), SensorModel(), settle=3)
    assert one.forces == two.forces and one.M_L_reach == two.M_L_reach
    assert one.M_L_settle == two.M_L_settle
    assert np.isfinite(one.peak_force_N)
