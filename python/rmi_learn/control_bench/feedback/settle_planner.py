"""``mpc-settle`` and ``model-constant``: control on a learned model of the settled water.

The model is action-conditioned: from the sensor window at control step t (the features of
:func:`~rmi_learn.control_bench.feedback.release.release_features`, F_hold included), a
candidate setpoint c held for the r control steps left in the task, and then the release to
F_hold, it predicts the water the sponge will hold after the settle, as the weight estimate
at t minus a ridge regression of the water that will not be back in the pores. The plan
terms are r, the change of grip d = c - u(t) (u(t) the setpoint applied last) and its
products with r and with itself; they vanish at r = 0 (release now).

It learns from the release probes' whole paths (every control step of each probe, with the
steps left to its release), per fold from the other groups' tuning states only, on the
input set (:data:`FEATURE_SETS`) that predicts best at the probes' starts when each training
group is left out in turn: the wrist load's changes over the window carry most of the
information on the 8 and 10 cm sponges and mislead on some 12 cm runs, where the load
swings with the sponge in the pads. ``mpc-settle`` re-plans every ``replan_ticks`` control
steps: it scores ``candidates`` setpoints spaced evenly over the benchmark's bounds and
applies the one whose predicted settled water is closest to the goal. ``model-constant``
plans once, at the start state, and holds that setpoint: the learned counterpart of the
constant-setpoint oracle. Both see only the sensors.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rmi_learn.control_bench.feedback.episode import Tick
from rmi_learn.control_bench.feedback.estimators import Ridge, feature_names, raw_weight
from rmi_learn.control_bench.feedback.release import (
    left_out_rms,
    own_group_rows,
    release_features,
    training_rows,
)

#: The controllers: re-planning every ``replan_ticks``, and planning once at the start state.
PLANNER_CONTROLLER = "mpc-settle"
CONSTANT_CONTROLLER = "model-constant"
PLANNERS = (PLANNER_CONTROLLER, CONSTANT_CONTROLLER)
_GRIP = ["w", "F_meas", "mean w", "mean F_meas", "first w", "first F_meas"]
_TAIL = ["u", "mean u", "m_dry", "F_hold"]
#: The model's candidate input sets, by name (entries of the release features): the whole
#: window; the grip (width and load, latest, window mean and first) and the wrist load's
#: change; the grip alone. Each ends with the setpoints, the dry mass and F_hold.
FEATURE_SETS: dict[str, list[str]] = {
    "window": [*feature_names(), "F_hold"],
    "grip-and-wrist": [*_GRIP, "change W_z", "mean change W_z", *_TAIL],
    "grip": [*_GRIP, *_TAIL],
}
_NAMES = FEATURE_SETS["window"]
_U_LAST = -4  # the last applied setpoint: every input set ends with _TAIL


def plan_features(base: np.ndarray, setpoints: np.ndarray, remaining: Any) -> np.ndarray:
    """The model's inputs (n, D + 5) for input features ``base`` (D,) or (n, D) ending with
    the last applied setpoint, the window's mean setpoint, the dry mass and F_hold, and
    candidate setpoints (n,) N held for ``remaining`` control steps r: ``base``, r, d, d r,
    d^2, d^2 r with d = setpoint - last applied setpoint (N), d = 0 at r = 0."""
    c = np.asarray(setpoints, dtype=np.float64)
    b = np.broadcast_to(np.asarray(base, dtype=np.float64), (c.size, np.shape(base)[-1]))
    r = np.broadcast_to(np.asarray(remaining, dtype=np.float64), c.shape)
    d = np.where(r > 0, c - b[:, _U_LAST], 0.0)
    return np.column_stack([b, r, d, d * r, d * d, d * d * r])


@dataclass(frozen=True)
class SettleModel:
    """The ridge ``ridge`` on the plan features of the release features' entries
    ``columns`` (the input set ``inputs``)."""

    ridge: Ridge
    columns: tuple[int, ...]
    inputs: str

    @staticmethod
    def of(inputs: str) -> tuple[int, ...]:
        """The entries of the release features that the input set ``inputs`` reads."""
        return tuple(_NAMES.index(n) for n in FEATURE_SETS[inputs])

    def x(self, base: np.ndarray, setpoints: Any, remaining: Any) -> np.ndarray:
        """:func:`plan_features` of the release features ``base`` (D,) or (n, D)."""
        return plan_features(np.asarray(base)[..., list(self.columns)], setpoints, remaining)

    def outside(self, base: np.ndarray, setpoints: Any, remaining: Any) -> np.ndarray:
        """The water (kg) that will not be back in the pores, per candidate setpoint (N)."""
        return self.ridge.predict(self.x(base, setpoints, remaining))


@dataclass
class PlanFit:
    """The settled-water model of one fold and its diagnostics (RMS errors, kg)."""

    model: SettleModel
    report: dict[str, Any]


def fit_plan(
    rows: Sequence[Mapping[str, Any]],
    size: int,
    fold: str,
    penalty: float,
    inputs: Sequence[str] = ("window",),
) -> PlanFit | None:
    """The model of ``fold`` of ``size`` from every path row of the other groups' probes,
    ridge ``penalty`` on standardised inputs (None without a successful probe), on the
    input set of ``inputs`` with the least RMS error at the probes' starts when each of
    those groups is left out in turn (the start is where every plan begins from a state
    the model has not seen). Its report gives each set's left-out errors, the RMS error on
    the training rows, for the chosen set the left-out errors over whole paths and, as a
    diagnostic, the errors on the probes of the fold's own group (whole paths and starts)."""
    mine = training_rows(rows, size, fold)
    if not mine:
        return None
    base = np.array([r["features"] for r in mine], dtype=np.float64)
    c = np.array([r["setpoint_N"] for r in mine], dtype=np.float64)
    left = np.array([int(r.get("remaining") or 0) for r in mine])
    y = np.array([r["target_kg"] for r in mine], dtype=np.float64)
    start = left == np.array([int(r["release_tick"]) for r in mine])
    everywhere = np.ones(len(mine), dtype=bool)
    folds = [r["fold"] for r in mine]
    xs = {name: plan_features(base[:, list(SettleModel.of(name))], c, left) for name in inputs}
    scores = {
        name: left_out_rms(x, y, folds, penalty, [everywhere, start]) for name, x in xs.items()
    }

    def start_rms(name: str) -> float:
        v = list(scores[name][1].values())
        return float(np.sqrt(np.mean(np.square(v)))) if v else np.inf

    best = min(inputs, key=start_rms)
    x = xs[best]
    ridge = Ridge.fit(x, y, penalty)
    report = {
        "plan_rows": len(mine),
        "plan_penalty": penalty,
        "plan_inputs": best,
        "plan_inputs_start_rms_kg": {n: start_rms(n) for n in inputs},
        "plan_rms_kg": float(np.sqrt(np.mean(np.square(ridge.predict(x) - y)))),
        "plan_left_out_rms_kg": scores[best][0],
        "plan_left_out_start_rms_kg": scores[best][1],
    }
    model = SettleModel(ridge, SettleModel.of(best), best)
    own = own_group_rows(rows, size, fold)
    if own:
        b = np.array([r["features"] for r in own], dtype=np.float64)
        k = np.array([int(r.get("remaining") or 0) for r in own])
        e = model.outside(b, [r["setpoint_N"] for r in own], k) - [r["target_kg"] for r in own]
        first = k == np.array([int(r["release_tick"]) for r in own])
        report["plan_own_group_rms_kg"] = float(np.sqrt(np.mean(np.square(e))))
        if first.any():
            report["plan_own_group_start_rms_kg"] = float(np.sqrt(np.mean(np.square(e[first]))))
    return PlanFit(model, report)


@dataclass
class SettlePlanner:
    """Receding horizon toward the settled goal ``goal_kg`` (kg) over ``horizon`` control
    steps, setpoints within [``lo_N``, ``hi_N``] N, for a sponge of dry mass ``m_dry`` (kg)
    released to ``hold_N`` (N)."""

    model: SettleModel
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
    _cs: np.ndarray = field(default_factory=lambda: np.empty(0))

    def start(self, history: list[Tick]) -> None:
        self._ticks, self._i = list(history), 0
        self._u = min(max(history[-1].applied, self.lo_N), self.hi_N)
        self._cs = np.linspace(self.lo_N, self.hi_N, self.candidates)

    def predict(self, setpoints: np.ndarray, remaining: int) -> np.ndarray:
        """The settled water (kg) predicted for each setpoint (N) held ``remaining`` steps
        from the latest tick seen."""
        base = release_features(self._ticks, self.m_dry, self.hold_N)
        outside = self.model.outside(base, setpoints, remaining)
        return raw_weight(self._ticks, self.m_dry) - outside

    def act(self, tick: Tick) -> float:
        if tick is not self._ticks[-1]:
            self._ticks.append(tick)
        if self._i % self.replan_ticks == 0:
            m_hat = self.predict(self._cs, self.horizon - self._i)
            self._u = float(self._cs[int(np.argmin(np.abs(m_hat - self.goal_kg)))])
        self._i += 1
        return self._u


__all__ = [
    "CONSTANT_CONTROLLER",
    "FEATURE_SETS",
    "PLANNERS",
    "PLANNER_CONTROLLER",
    "PlanFit",
    "SettleModel",
    "SettlePlanner",
    "fit_plan",
    "plan_features",
]
