"""Release probes: what the sponge keeps once the pads return to F_hold.

The ``settle`` task scores M_L 0.5 s after the release, and the sponge takes back part of
the water the squeeze pressed onto its surface as it re-expands, so a loop that drives
M_L (or an estimate of it) to the goal ends above it. A controller that predicts the
release can aim where the water will settle instead.

A probe executes, from a tuning state, a constant setpoint for ``k`` control steps and then
the settle at F_hold, and records its features at the release (the sensor window's
:func:`~rmi_learn.control_bench.feedback.estimators.window_features` with the protocol's
noise and latency, and F_hold, the grip the pads return to) and its target: the weight
estimate at the release minus the true M_L after the settle, the water that will not be
back in the pores. The ``pi-settle`` estimator is the weight estimate minus a ridge
regression of that target on the features (the water the sponge would keep if released
now), fitted per fold on the other groups' probes with the protocol's fixed penalty. Probes
use only tuning states, which serve the folds of the other groups.

Why F_hold and a fixed penalty: without F_hold, each held-out group's settle estimate was
off by about 5 g in the direction of its F_hold (the re-expansion at a firmer holding grip
leaves more water outside), and choosing the penalty by leaving one training group out
picks a heavy one whenever the group left out is the only one at its F_hold, which undoes
the F_hold term. Both choices were made on the release probes of the tuning states before
any test state was executed (docs/control.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.control_bench.feedback.episode import Tick
from rmi_learn.control_bench.feedback.estimators import (
    LearnedEstimate,
    Ridge,
    raw_weight,
    tick_features,
)
from rmi_learn.control_bench.feedback.held_out import fold_of
from rmi_learn.control_bench.feedback.laws import Fixed

#: The controller that closes its loop on the predicted settled water.
SETTLE_CONTROLLER = "pi-settle"
#: Noise keys of the probes start here, clear of the tasks' indices.
_PROBE_KEY = 100
#: Columns of the probes' checkpoint file.
PROBE_SCHEMA: dict[str, Any] = {
    "run_id": pl.String,
    "size_cm": pl.Int64,
    "fold": pl.String,
    "tick": pl.Int64,
    "setpoint_N": pl.Float64,
    "release_tick": pl.Int64,
    "remaining": pl.Int64,
    "status": pl.String,
    "target_kg": pl.Float64,
    "features": pl.List(pl.Float64),
}


def probe_plan(protocol: Mapping[str, Any], lo_N: float, hi_N: float) -> list[tuple[float, int]]:
    """The (setpoint N, release tick) pairs of one tuning state: ``release_probes.setpoints``
    setpoints spaced evenly over [``lo_N``, ``hi_N``] (both ends included), each released
    after every one of ``release_probes.ticks`` control steps."""
    spec = protocol["release_probes"]
    cs = np.linspace(lo_N, hi_N, int(spec["setpoints"]))
    return [(float(c), int(k)) for c in cs for k in spec["ticks"]]


def release_features(seen: Sequence[Tick], m_dry: float, hold_N: float) -> np.ndarray:
    """The estimator's features of the last ticks seen (observed rows and setpoints) for a
    sponge of dry mass ``m_dry`` (kg) released to ``hold_N`` (N)."""
    return tick_features(list(seen), m_dry, (hold_N,))


def SettleEstimate(model: Ridge, m_dry: float, hold_N: float) -> LearnedEstimate:  # noqa: N802
    """The water M_L will settle at (kg): the weight estimate of a sponge of dry mass
    ``m_dry`` (kg) minus the water the ridge ``model`` predicts to stay outside the pores
    once released to ``hold_N`` (N)."""
    return LearnedEstimate(model, m_dry, (float(hold_N),))


def probe_rows(work: Any, path: bool = False) -> list[dict[str, Any]]:
    """Execute the probes of one tuning state (a worker's ``StateWork``) and return their
    rows: one at the release (``remaining`` 0) and, with ``path``, one at every earlier
    control step of the probe too (``remaining`` the steps left to its release), whose
    target is the weight estimate there minus the same settled M_L. A failed probe keeps
    its status and no target."""
    job, snap, plant = work.job, work.snap, work.plant
    n_past = len(snap.history)
    out = []
    for j, (c, k) in enumerate(probe_plan(job.protocol, plant.lo_N, plant.hi_N)):
        e = work.run(Fixed([c]), True, True, _PROBE_KEY + j, horizon=k, keep_seen=True)
        ok = e.status == "ok" and e.M_L_settle is not None
        base: dict[str, Any] = {
            "run_id": job.run.run_id,
            "size_cm": job.run.size_cm,
            "fold": fold_of(job.run),
            "tick": snap.tick,
            "setpoint_N": c,
            "release_tick": k,
            "status": e.status,
        }
        if not ok:
            out.append({**base, "remaining": 0, "target_kg": None, "features": None})
            continue
        for left in range(k, -1, -1) if path else [0]:
            seen = e.seen[: n_past + k - left]
            out.append(
                {
                    **base,
                    "remaining": left,
                    "target_kg": raw_weight(seen, work.m_dry) - float(e.M_L_settle),
                    "features": release_features(seen, work.m_dry, plant.hold_N).tolist(),
                }
            )
    return out


@dataclass
class SettleFit:
    """The settle regression of one fold and its diagnostics (RMS errors, kg)."""

    model: Ridge
    report: dict[str, Any]


def fit_settle(
    rows: Sequence[Mapping[str, Any]], size: int, fold: str, penalty: float
) -> SettleFit | None:
    """The settle regression of ``fold`` of ``size`` from the probes of the other groups,
    ridge ``penalty`` on standardised features (None when they have no successful probe);
    its report gives the RMS error on those probes, on each of those groups left out in
    turn and, as a diagnostic, on the probes of the fold's own group."""
    mine = [r for r in training_rows(rows, size, fold) if not r.get("remaining")]
    if not mine:
        return None
    x = np.array([r["features"] for r in mine], dtype=np.float64)
    y = np.array([r["target_kg"] for r in mine], dtype=np.float64)
    model = Ridge.fit(x, y, penalty)
    (left_out,) = left_out_rms(x, y, [r["fold"] for r in mine], penalty)
    report = {
        "probes": len(mine),
        "settle_penalty": penalty,
        "settle_rms_kg": _rms(model.predict(x) - y),
        "settle_left_out_rms_kg": left_out,
        "settle_target_mean_kg": float(np.mean(y)),
        "settle_target_std_kg": float(np.std(y)),
    }
    own = [r for r in own_group_rows(rows, size, fold) if not r.get("remaining")]
    if own:
        xo = np.array([r["features"] for r in own], dtype=np.float64)
        yo = np.array([r["target_kg"] for r in own], dtype=np.float64)
        report["settle_own_group_rms_kg"] = _rms(model.predict(xo) - yo)
    return SettleFit(model, report)


def training_rows(
    rows: Sequence[Mapping[str, Any]], size: int, fold: str
) -> list[Mapping[str, Any]]:
    """The successful probe rows of ``size`` that ``fold`` may learn from (other groups')."""
    return _successful(rows, size, fold, own=False)


def own_group_rows(
    rows: Sequence[Mapping[str, Any]], size: int, fold: str
) -> list[Mapping[str, Any]]:
    """The successful probe rows of ``fold``'s own group (from its tuning states, which serve
    the other folds): for a diagnostic after the fit, never for a choice."""
    return _successful(rows, size, fold, own=True)


def _successful(
    rows: Sequence[Mapping[str, Any]], size: int, fold: str, own: bool
) -> list[Mapping[str, Any]]:
    return [
        r
        for r in rows
        if r["size_cm"] == size and (r["fold"] == fold) == own and r["target_kg"] is not None
    ]


def left_out_rms(
    x: np.ndarray,
    y: np.ndarray,
    folds: Sequence[str],
    penalty: float,
    masks: Sequence[np.ndarray] | None = None,
) -> list[dict[str, float]]:
    """For each of ``masks`` (default: all rows), the RMS error (kg) on each group's masked
    rows of the ridge fitted with ``penalty`` on the other groups' rows (``folds``: each
    row's group)."""
    labels = sorted(set(folds))
    groups = np.array([labels.index(f) for f in folds])
    masks = [np.ones(len(folds), dtype=bool)] if masks is None else masks
    out: list[dict[str, float]] = [{} for _ in masks]
    for g, label in enumerate(labels):
        if not (groups != g).any():
            continue
        m = Ridge.fit(x[groups != g], y[groups != g], penalty)
        for held, mask in zip(out, masks, strict=True):
            te = (groups == g) & mask
            if te.any():
                held[label] = _rms(m.predict(x[te]) - y[te])
    return out


def _rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(e))))


__all__ = [
    "PROBE_SCHEMA",
    "SETTLE_CONTROLLER",
    "SettleEstimate",
    "SettleFit",
    "fit_settle",
    "left_out_rms",
    "own_group_rows",
    "probe_plan",
    "probe_rows",
    "release_features",
    "training_rows",
]
