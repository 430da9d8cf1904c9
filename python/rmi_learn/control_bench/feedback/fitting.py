"""Fitting the sensor-mode estimators on the tuning runs' records.

The records of a run are taken on the control grid (every 20 ms; a run file records every
``record_every`` engine steps, a whole fraction of it), turned into what the sensors would
have reported (:func:`rmi_learn.sensing.observe_rows`, the protocol's noise and latency,
seeded per run) and kept where the run is in the protocol's start phases.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from rmi_learn.control_bench.feedback.estimators import (
    W_INDEX,
    LearnedEstimate,
    Ridge,
    WidthEstimate,
    fit_ridge_grouped,
    run_features,
)
from rmi_learn.control_bench.feedback.held_out import RunInfo
from rmi_learn.data.runs import read_run
from rmi_learn.data.schema import CONTROL_DT
from rmi_learn.sensing import SENSOR_NAMES, SensorModel, observe_rows, weight_estimate

if TYPE_CHECKING:
    from rmi_learn.control_bench.feedback.settle_planner import SettleModel


def run_key(run: RunInfo) -> tuple[int, ...]:
    """Integers that name a run for seeding: size, porosity, F_hold, F_squeeze, seed."""
    return (
        run.size_cm,
        round(run.porosity * 1000),
        round(run.F_hold * 10),
        round(run.F_squeeze * 10),
        run.seed,
    )


@dataclass
class RunRows:
    """A run's control-grid rows in the start phases: observed sensor rows, their features,
    true M_L (kg)."""

    observed: np.ndarray
    features: np.ndarray
    m_l: np.ndarray


def run_rows(run: RunInfo, sensors: SensorModel, phases: Sequence[str], m_dry: float) -> RunRows:
    """The rows of ``run`` (dry sponge ``m_dry`` kg) the estimators learn from."""
    df, _ = read_run(run.path)
    t = df["time"].to_numpy()
    on_grid = np.abs(t / CONTROL_DT - np.round(t / CONTROL_DT)) < 1e-6
    d = df.filter(on_grid)
    true = np.stack([d[n].to_numpy().astype(np.float64) for n in SENSOR_NAMES], axis=1)
    observed = observe_rows(true, sensors, run_key(run))
    applied = d["F_target"].to_numpy().astype(np.float64)
    feats = run_features(observed, applied, m_dry)
    keep = np.isin(d["phase"].to_numpy().astype(str), list(phases))
    return RunRows(observed[keep], feats[keep], d["M_L"].to_numpy()[keep])


@dataclass
class Fits:
    """The fitted estimators of one size, with their diagnostics (RMS errors, kg); the
    weight estimate takes the executed sponge's own dry mass beside the fitted offset.
    ``settle`` is the settle-predicting regression, fitted on release probes
    (:mod:`rmi_learn.control_bench.feedback.release`) when the protocol lists it; ``plan``
    the settled-water model of ``mpc-settle`` and ``model-constant`` (a ``SettleModel``)
    fitted on the probes' paths
    (:mod:`rmi_learn.control_bench.feedback.settle_planner`)."""

    weight_offset_kg: float
    width: WidthEstimate
    learned: LearnedEstimate
    report: dict[str, Any]
    settle: Ridge | None = None
    plan: SettleModel | None = None


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


def fit_size(
    runs: Sequence[RunInfo], rows: Mapping[str, RunRows], dry: Mapping[str, float]
) -> Fits:
    """Fit the weight offset, the width map and the learned estimator on ``runs`` (the
    training runs of one size and fold), from their :func:`run_rows` by run id; ``dry`` maps
    run id to the dry sponge's mass (kg)."""
    m_l = np.concatenate([rows[r.run_id].m_l for r in runs])
    raw = np.concatenate(
        [
            weight_estimate(rows[r.run_id].observed[:, SENSOR_NAMES.index("W_z")], dry[r.run_id])
            for r in runs
        ]
    )
    surface = raw - m_l
    offset = float(np.mean(surface))
    w = np.concatenate([rows[r.run_id].observed[:, W_INDEX] for r in runs])
    b, a = np.polyfit(w, surface, 1)
    x = np.concatenate([rows[r.run_id].features for r in runs])
    labels = sorted({r.group for r in runs})
    groups = np.concatenate([np.full(rows[r.run_id].m_l.size, labels.index(r.group)) for r in runs])
    model, cv = fit_ridge_grouped(x, surface, groups)
    report = {
        "rows": int(m_l.size),
        "runs": len(runs),
        "weight_offset_kg": offset,
        "weight_rms_kg": _rms(raw - offset - m_l),
        "width_a_kg": float(a),
        "width_b_kg_per_m": float(b),
        "width_rms_kg": _rms(a + b * w - surface),
        "learned_penalty": model.penalty,
        "learned_cv_rms_kg": cv,
        "learned_rms_kg": _rms(model.predict(x) - surface),
    }
    return Fits(offset, WidthEstimate(float(a), float(b)), LearnedEstimate(model), report)


__all__ = ["Fits", "RunRows", "fit_size", "run_key", "run_rows"]
