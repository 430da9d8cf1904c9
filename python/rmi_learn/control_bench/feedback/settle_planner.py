"""``mpc-settle``: receding-horizon control on a learned model of the settled water.

The model is action-conditioned: from the sensor window at control step t (the features of
:func:`~rmi_learn.control_bench.feedback.release.release_features`, F_hold included), a
candidate setpoint c held for the r control steps left in the task, and then the release to
F_hold, it predicts the water the sponge will hold after the settle, as the weight estimate
at t minus a ridge regression of the water that will not be back in the pores. The plan
terms are r, the change of grip d = c - u(t) (u(t) the setpoint applied last) and its
products with r and with itself; they vanish at r = 0 (release now), where the model reads
what the settle regression of ``pi-settle`` reads.

It learns from the release probes' whole paths (every control step of each probe, with the
steps left to its release), per fold from the other groups' tuning states only. Every
``replan_ticks`` control steps the controller scores ``candidates`` setpoints spaced evenly
over the benchmark's bounds and applies the one whose predicted settled water is closest to
the goal; it sees only the sensors.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rmi_learn.control_bench.feedback.episode import Tick
from rmi_learn.control_bench.feedback.estimators import Ridge, raw_weight
from rmi_learn.control_bench.feedback.release import (
    left_out_rms,
    release_features,
    training_rows,
)

#: The controller's name in protocols and tables.
PLANNER_CONTROLLER = "mpc-settle"
#: Index of the last applied setpoint in the release features (then the window's mean
#: setpoint, the dry mass and F_hold).
_U_LAST = -4


def plan_features(
    base: np.ndarray, setpoints: np.ndarray, remaining: int | np.ndarray
) -> np.ndarray:
    """The model's inputs (n, D + 5) for release features ``base`` (D,) or (n, D), candidate
    setpoints (n,) N held for ``remaining`` control steps r: ``base``, r, d, d r, d^2, d^2 r
    with d = setpoint - last applied setpoint (N), d = 0 at r = 0."""
    c = np.asarray(setpoints, dtype=np.float64)
    b = np.broadcast_to(np.asarray(base, dtype=np.float64), (c.size, np.shape(base)[-1]))
    r = np.broadcast_to(np.asarray(remaining, dtype=np.float64), c.shape)
    d = np.where(r > 0, c - b[:, _U_LAST], 0.0)
    return np.column_stack([b, r, d, d * r, d * d, d * d * r])


@dataclass
class PlanFit:
    """The settled-water model of one fold and its diagnostics (RMS errors, kg)."""

    model: Ridge
    report: dict[str, Any]


def fit_plan(
    rows: Sequence[Mapping[str, Any]], size: int, fold: str, penalty: float
) -> PlanFit | None:
    """The model of ``fold`` of ``size`` from every path row of the other groups' probes,
    ridge ``penalty`` on standardised inputs (None without a successful probe); its report
    gives the RMS error on those rows, on each of those groups left out in turn, and on the
    rows of a probe's start (the prediction over a whole probe)."""
    mine = training_rows(rows, size, fold)
    if not mine:
        return None
    base = np.array([r["features"] for r in mine], dtype=np.float64)
    c = np.array([r["setpoint_N"] for r in mine], dtype=np.float64)
    left = np.array([int(r.get("remaining") or 0) for r in mine])
    x = plan_features(base, c, left)
    y = np.array([r["target_kg"] for r in mine], dtype=np.float64)
    start = left == np.array([int(r["release_tick"]) for r in mine])
    model = Ridge.fit(x, y, penalty)
    everywhere = np.ones(len(mine), dtype=bool)
    held, held_start = left_out_rms(x, y, [r["fold"] for r in mine], penalty, [everywhere, start])
    report = {
        "plan_rows": len(mine),
        "plan_penalty": penalty,
        "plan_rms_kg": float(np.sqrt(np.mean(np.square(model.predict(x) - y)))),
        "plan_left_out_rms_kg": held,
        "plan_left_out_start_rms_kg": held_start,
    }
    return PlanFit(model, report)


@dataclass
class SettlePlanner:
    """Receding horizon toward the settled goal ``goal_kg`` (kg) over ``horizon`` control
    steps, setpoints within [``lo_N``, ``hi_N``] N, for a sponge of dry mass ``m_dry`` (kg)
    released to ``hold_N`` (N)."""

    model: Ridge
    m_dry: float
    hold_N: float
    goal_kg: float
    horizon: int
    lo_N: float
    hi_N: float
    candidates: int
    replan_ticks: int
    _ticks: list[Tick] = field(default_factory=list)
    _i: int = 0
    _u: float = 0.0

    def start(self, history: list[Tick]) -> None:
        self._ticks, self._i = list(history), 0
        self._u = min(max(history[-1].applied, self.lo_N), self.hi_N)

    def predict(self, setpoints: np.ndarray, remaining: int) -> np.ndarray:
        """The settled water (kg) predicted for each setpoint (N) held ``remaining`` steps
        from the latest tick seen."""
        base = release_features(self._ticks, self.m_dry, self.hold_N)
        outside = self.model.predict(plan_features(base, setpoints, remaining))
        return raw_weight(self._ticks, self.m_dry) - outside

    def act(self, tick: Tick) -> float:
        if tick is not self._ticks[-1]:
            self._ticks.append(tick)
        if self._i % self.replan_ticks == 0:
            cs = np.linspace(self.lo_N, self.hi_N, self.candidates)
            m_hat = self.predict(cs, self.horizon - self._i)
            self._u = float(cs[int(np.argmin(np.abs(m_hat - self.goal_kg)))])
        self._i += 1
        return self._u


__all__ = ["PLANNER_CONTROLLER", "PlanFit", "SettlePlanner", "fit_plan", "plan_features"]
