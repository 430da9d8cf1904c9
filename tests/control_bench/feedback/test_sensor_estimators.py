"""Estimates of the retained water from the sensors (control_bench.feedback.estimators and
.fitting): the ridge fit, the grouped choice of its penalty, the window features, and that
each estimator reads only what the sensors report."""

from __future__ import annotations

import numpy as np
import pytest

from rmi_learn.control_bench.feedback.episode import Tick
from rmi_learn.control_bench.feedback.estimators import (
    RIDGE_PENALTIES,
    WINDOW,
    LearnedEstimate,
    Ridge,
    WidthEstimate,
    feature_names,
    fit_ridge_grouped,
    run_features,
    window_features,
)
from rmi_learn.sensing import SENSOR_NAMES, STANDARD_GRAVITY


def test_a_ridge_with_a_small_penalty_recovers_a_linear_map() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 3))
    y = x @ [1.0, -2.0, 0.5] + 3.0
    m = Ridge.fit(x, y, 1e-9)
    assert np.allclose(m.predict(x), y, atol=1e-6)


def test_the_grouped_penalty_is_scored_on_groups_left_out() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(300, 4))
    y = x[:, 0] + 0.1 * rng.normal(size=300)
    groups = np.repeat([0, 1, 2], 100)
    m, cv = fit_ridge_grouped(x, y, groups)
    assert set(cv) == {repr(p) for p in RIDGE_PENALTIES}
    assert m.penalty == min(RIDGE_PENALTIES, key=lambda p: cv[repr(p)])


def test_window_features_pad_a_short_history_and_see_only_wrist_load_changes() -> None:
    c = len(SENSOR_NAMES)
    obs = np.arange(3 * c, dtype=float).reshape(3, c)
    f = window_features(obs, np.array([1.0, 2.0, 3.0]), 0.1)
    assert f.shape == window_features(np.zeros((WINDOW + 5, c)), np.zeros(WINDOW + 5), 0.1).shape
    shifted = obs.copy()
    shifted[:, SENSOR_NAMES.index("W_z")] -= 5.0  # a heavier sponge, same changes
    assert np.array_equal(window_features(shifted, np.array([1.0, 2.0, 3.0]), 0.1), f)
    assert run_features(obs, np.array([1.0, 2.0, 3.0]), 0.1).shape == (3, f.size)


def _tick(w: float, w_z: float, m_l: float) -> Tick:
    obs = np.zeros(len(SENSOR_NAMES))
    obs[SENSOR_NAMES.index("w")] = w
    obs[SENSOR_NAMES.index("W_z")] = w_z
    return Tick({"M_L": m_l, "F_target": 10.0}, obs, 10.0)


def test_sensor_estimates_subtract_the_surface_water_from_the_weight() -> None:
    t = _tick(0.07, -STANDARD_GRAVITY * 1.0, m_l=123.0)
    width = WidthEstimate(a=0.5, b=-5.0, m_dry=0.1)
    assert width([t]) == pytest.approx(1.0 - 0.1 - (0.5 - 5.0 * 0.07))
    assert width([t]) == width([_tick(0.07, -STANDARD_GRAVITY * 1.0, m_l=-1.0)])
    zero = Ridge(np.zeros(1), np.ones(1), np.zeros(1), 0.02, 1.0)
    x = window_features(np.stack([t.observed]), np.array([10.0]), 0.1)
    learned = LearnedEstimate(
        Ridge(np.zeros(x.size), np.ones(x.size), np.zeros(x.size), 0.02, 1.0), 0.1
    )
    assert learned([t]) == pytest.approx(1.0 - 0.1 - 0.02)
    assert zero.predict(np.zeros((2, 1))).tolist() == [0.02, 0.02]


def test_the_feature_names_label_each_window_feature() -> None:
    obs = np.tile(np.arange(len(SENSOR_NAMES), dtype=np.float64), (4, 1))
    obs[-1] += 100.0  # the latest row differs from the first and the mean
    x = window_features(obs, np.full(4, 30.0), 0.05)
    names = feature_names()
    assert len(names) == x.size and len(set(names)) == len(names)
    assert x[names.index("w")] == obs[-1, SENSOR_NAMES.index("w")]
    assert x[names.index("first F_meas")] == obs[0, SENSOR_NAMES.index("F_meas")]
    assert x[names.index("change W_z")] == 100.0
    assert x[names.index("u")] == 30.0 and x[names.index("m_dry")] == 0.05
