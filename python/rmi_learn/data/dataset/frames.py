"""Frames of a run on the 20 ms control grid: resampling and the rows kept for learning."""

from __future__ import annotations

import math

import numpy as np
import polars as pl

from rmi_learn.data.schema import (
    ACTIONS,
    CONTINUOUS,
    CONTROL_DT,
    LEARNING_PHASES,
    OBS,
    WRIST,
)

#: Categorical channels of y (held, never interpolated or standardised).
CATEGORICAL: tuple[str, ...] = tuple(n for n in OBS if n not in CONTINUOUS)
#: Index of retained water M_L within the 18 continuous channels.
WATER_INDEX = CONTINUOUS.index("M_L")
_TOL = 1e-9  # s, grid-time matching tolerance


def resample_run(df: pl.DataFrame, dt: float = CONTROL_DT) -> dict[str, np.ndarray]:
    """Resample one run's rows to the global grid ``k * dt`` (s) inside its recorded span.

    Returns arrays keyed ``k`` (int64 grid index), ``time`` (= ``k * dt``), ``phase`` (str),
    every name in OBS and ACTIONS, and the wrist load (WRIST) where ``df`` has it.
    Continuous channels are linearly interpolated; a value is NaN if either bracketing record
    is NaN (only ``v_res`` may be). Categorical channels (c, r_*, phase) take the last record
    at or before the grid time.
    """
    t = df["time"].to_numpy().astype(np.float64)
    if t.size == 0:
        raise ValueError("empty run")
    k0 = math.ceil(t[0] / dt - 1e-6)
    k1 = math.floor(t[-1] / dt + 1e-6)
    k = np.arange(k0, k1 + 1, dtype=np.int64)
    grid = k * dt
    # Continuous: bracketing records lo <= grid <= hi.
    hi = np.searchsorted(t, grid - _TOL, side="left")
    hi = np.clip(hi, 0, t.size - 1)
    exact = np.abs(t[hi] - grid) <= _TOL
    lo = np.clip(hi - 1, 0, t.size - 1)
    span = t[hi] - t[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        wgt = np.where(span > 0, (grid - t[lo]) / np.where(span > 0, span, 1.0), 0.0)
    # Categorical: last record at or before the grid time.
    held = np.searchsorted(t, grid + _TOL, side="right") - 1
    held = np.clip(held, 0, t.size - 1)

    out: dict[str, np.ndarray] = {"k": k, "time": grid.copy()}
    out["phase"] = df["phase"].to_numpy().astype(str)[held]
    for name in OBS + ACTIONS + tuple(n for n in WRIST if n in df.columns):
        x = df[name].to_numpy().astype(np.float64)
        if name in CATEGORICAL:
            out[name] = x[held]
        else:
            interp = x[lo] * (1.0 - wgt) + x[hi] * wgt
            out[name] = np.where(exact, x[hi], interp)
    return out


def select_learning_rows(phase: np.ndarray) -> np.ndarray:
    """Boolean mask of grid rows kept for learning: phase in LEARNING_PHASES, minus the first
    grid row of ``close`` (the initial velocity command)."""
    keep = np.isin(phase, np.asarray(LEARNING_PHASES))
    close = np.flatnonzero(phase == "close")
    if close.size:
        keep[close[0]] = False
    return keep
