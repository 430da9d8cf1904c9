"""Estimates of the retained water M_L (kg) a feedback loop closes on.

- ``privileged``: the simulator's own M_L (the paper's y_t shows it).
- ``weight``: the wrist load's weight estimate (:func:`rmi_learn.sensing.weight_estimate`),
  its carried-water offset fitted on the tuning runs.
- ``width``: the weight estimate minus the water pressed out onto the surface, an affine
  map of the gripper width a + b w fitted on the training runs: while the water stays on the
  sponge the weight cannot tell pore water from surface water, and what the squeeze pressed
  out follows the compression.
- ``learned``: the weight estimate minus a ridge regression of the surface water on
  features of the sensor history (the latest row, the mean of the window, the row at its
  start, the setpoints applied, the dry mass), fitted on the training runs' sensor rows
  (noise and latency of the protocol's sensor model), its regularisation chosen by leaving
  one training group out.

The width and learned estimators learn the surface water, not M_L itself: the surface
water hardly depends on the foam's porosity, which sets the level of M_L and which the
held-out group may not share with the training groups.

Each estimator reads only what its mode observes: the ``sensors`` ones never see M_L.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rmi_learn.control_bench.feedback.episode import Tick
from rmi_learn.sensing import SENSOR_NAMES, weight_estimate

W_INDEX = SENSOR_NAMES.index("w")
WZ_INDEX = SENSOR_NAMES.index("W_z")
#: Control steps of sensor history the learned estimator reads.
WINDOW = 16
#: Ridge penalties tried (on standardised features).
RIDGE_PENALTIES = (1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0)
#: Channels whose level differs between sponges (the wrist load weighs the water): only
#: their changes over the window are features.
_W = [SENSOR_NAMES.index(n) for n in ("W_x", "W_y", "W_z")]
_REST = [i for i in range(len(SENSOR_NAMES)) if i not in _W]


def window_features(observed: np.ndarray, applied: np.ndarray, m_dry: float) -> np.ndarray:
    """Features of the last ``WINDOW`` observed rows (L, C) and applied setpoints (L,) N,
    L >= 1 (a shorter history repeats its first row): latest row, window mean and first row
    of every channel but the wrist load, the wrist load's change over the window (latest and
    mean minus first), latest setpoint, the setpoints' mean, and the dry sponge's mass
    ``m_dry`` (kg, weighed before the task)."""
    obs = np.asarray(observed, dtype=np.float64)
    u = np.asarray(applied, dtype=np.float64)
    if obs.shape[0] < WINDOW:
        pad = WINDOW - obs.shape[0]
        obs = np.concatenate([np.repeat(obs[:1], pad, axis=0), obs])
        u = np.concatenate([np.repeat(u[:1], pad), u])
    obs, u = obs[-WINDOW:], u[-WINDOW:]
    first, mean = obs[0], obs.mean(axis=0)
    return np.concatenate(
        [
            obs[-1, _REST],
            mean[_REST],
            first[_REST],
            obs[-1, _W] - first[_W],
            mean[_W] - first[_W],
            [u[-1], u.mean(), m_dry],
        ]
    )


def feature_names() -> list[str]:
    """The names of :func:`window_features`' entries, in order: ``X``, ``mean X`` and
    ``first X`` for every channel X but the wrist load, ``change W_i`` and ``mean change
    W_i`` for the wrist load, then ``u``, ``mean u`` and ``m_dry``."""
    rest = [SENSOR_NAMES[i] for i in _REST]
    wrist = [SENSOR_NAMES[i] for i in _W]
    return [
        *rest,
        *(f"mean {n}" for n in rest),
        *(f"first {n}" for n in rest),
        *(f"change {n}" for n in wrist),
        *(f"mean change {n}" for n in wrist),
        "u",
        "mean u",
        "m_dry",
    ]


def run_features(observed: np.ndarray, applied: np.ndarray, m_dry: float) -> np.ndarray:
    """:func:`window_features` at every row of one episode's observed rows (T, C)."""
    return np.stack(
        [
            window_features(observed[: t + 1], applied[: t + 1], m_dry)
            for t in range(observed.shape[0])
        ]
    )


@dataclass(frozen=True)
class Ridge:
    """A standardised linear model y = ((x - mean) / scale) . coef + intercept."""

    mean: np.ndarray
    scale: np.ndarray
    coef: np.ndarray
    intercept: float
    penalty: float

    @staticmethod
    def fit(x: np.ndarray, y: np.ndarray, penalty: float) -> Ridge:
        mean = x.mean(axis=0)
        scale = x.std(axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        z = (x - mean) / scale
        y0 = float(y.mean())
        a = z.T @ z + penalty * z.shape[0] * np.eye(z.shape[1])
        coef = np.linalg.solve(a, z.T @ (y - y0))
        return Ridge(mean, scale, coef, y0, float(penalty))

    def predict(self, x: np.ndarray) -> np.ndarray:
        return ((np.atleast_2d(x) - self.mean) / self.scale) @ self.coef + self.intercept


def fit_ridge_grouped(
    x: np.ndarray, y: np.ndarray, groups: np.ndarray
) -> tuple[Ridge, dict[str, float]]:
    """The ridge model on all rows, its penalty the one of ``RIDGE_PENALTIES`` with the least
    RMS error over leave-one-group-out fits (groups: one label per row); returns the model
    and each penalty's cross-validated RMS error (kg)."""
    labels = sorted(set(groups.tolist()))
    scores: dict[str, float] = {}
    for lam in RIDGE_PENALTIES:
        err = []
        for g in labels:
            tr, te = groups != g, groups == g
            if not tr.any():
                continue
            m = Ridge.fit(x[tr], y[tr], lam)
            err.append(m.predict(x[te]) - y[te])
        scores[repr(lam)] = float(np.sqrt(np.mean(np.concatenate(err) ** 2))) if err else np.nan
    best = min(RIDGE_PENALTIES, key=lambda lam: (np.nan_to_num(scores[repr(lam)], nan=np.inf), lam))
    return Ridge.fit(x, y, best), scores


class Estimator:
    """M_L (kg) from the ticks seen so far (the last is the current one)."""

    def __call__(self, ticks: Sequence[Tick]) -> float:
        raise NotImplementedError


class PrivilegedEstimate(Estimator):
    def __call__(self, ticks: Sequence[Tick]) -> float:
        return float(ticks[-1].record["M_L"])


@dataclass
class WeightEstimate(Estimator):
    """``m_dry`` the dry sponge (kg), ``offset`` the carried expelled water (kg)."""

    m_dry: float
    offset: float

    def __call__(self, ticks: Sequence[Tick]) -> float:
        obs = ticks[-1].observed
        assert obs is not None
        return float(weight_estimate(float(obs[WZ_INDEX]), self.m_dry, self.offset))


def raw_weight(ticks: Sequence[Tick], m_dry: float) -> float:
    """The weight estimate (kg) of the latest tick for a sponge of dry mass ``m_dry`` (kg),
    no offset."""
    obs = ticks[-1].observed
    assert obs is not None
    return float(weight_estimate(float(obs[WZ_INDEX]), m_dry))


def tick_features(ticks: Sequence[Tick], m_dry: float, extra: Sequence[float] = ()) -> np.ndarray:
    """:func:`window_features` of the last ``WINDOW`` ticks seen, then ``extra``."""
    rows = ticks[-WINDOW:]
    obs = np.stack([t.observed for t in rows if t.observed is not None])
    u = np.array([t.applied for t in rows])
    return np.append(window_features(obs, u, m_dry), np.asarray(extra, dtype=np.float64))


@dataclass
class WidthEstimate(Estimator):
    """The weight estimate of a sponge of dry mass ``m_dry`` (kg) minus the surface water
    a + b w (``a`` kg, ``b`` kg/m)."""

    a: float
    b: float
    m_dry: float = 0.0

    def __call__(self, ticks: Sequence[Tick]) -> float:
        obs = ticks[-1].observed
        assert obs is not None
        return raw_weight(ticks, self.m_dry) - (self.a + self.b * float(obs[W_INDEX]))


@dataclass
class LearnedEstimate(Estimator):
    """The weight estimate of a sponge of dry mass ``m_dry`` (kg) minus the water outside
    the pores that the ridge ``model`` predicts from :func:`tick_features` (with ``extra``
    appended)."""

    model: Ridge
    m_dry: float = 0.0
    extra: tuple[float, ...] = ()

    def __call__(self, ticks: Sequence[Tick]) -> float:
        outside = float(self.model.predict(tick_features(ticks, self.m_dry, self.extra))[0])
        return raw_weight(ticks, self.m_dry) - outside


__all__ = [
    "WINDOW",
    "Estimator",
    "LearnedEstimate",
    "PrivilegedEstimate",
    "Ridge",
    "WeightEstimate",
    "WidthEstimate",
    "feature_names",
    "fit_ridge_grouped",
    "raw_weight",
    "run_features",
    "tick_features",
    "window_features",
]
