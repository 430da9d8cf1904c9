"""A dataset's frames as the ``sensors`` observation mode shows them: what the gripper's
sensors report at each kept row (:mod:`rmi_learn.sensing`), and the dry sponge's mass.

The noise and latency follow one :class:`~rmi_learn.sensing.SensorModel` stream per
contiguous segment of a run (keyed by run and segment number), so a window's history is what
the sensors reported online in that segment, the same bits on every load. The dry mass is
what the robot weighs before the task; it sets the level the wrist load's weight is read
against, which a held-out porosity does not share with the training runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data.schema import WRIST
from rmi_learn.errors import InputError
from rmi_learn.sensing import SENSOR_NAMES, SensorModel, observe_rows

#: The channels a sensor-mode model reads, in order: the sensors, then the dry mass (kg).
SENSOR_INPUTS: tuple[str, ...] = (*SENSOR_NAMES, "m_dry")


@dataclass(frozen=True)
class SensorView:
    """The observed ``SENSOR_INPUTS`` of every frame row: ``values`` (N, C) in SI units,
    ``mean`` and ``std`` (C,) over the training runs' rows, ``standardised`` (N, C)
    float32 ``(values - mean) / std``."""

    model: SensorModel
    values: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    standardised: np.ndarray


def check_sensor_columns(root: Any, frames: pl.DataFrame, runs: pl.DataFrame) -> None:
    """Refuse a dataset without the wrist load or the dry masses (built by an older
    version): one line naming it and what to do."""
    missing = [c for c in WRIST if c not in frames.columns]
    if missing or "m_dry" not in runs.columns:
        what = ", ".join(missing) if missing else "m_dry"
        raise InputError(
            f"{root}: observation_mode 'sensors' needs the dataset's {what} (a dataset "
            "built before they were kept); rebuild it with rmi dataset build"
        )
    m_dry = runs["m_dry"].to_numpy()
    if not np.all(np.isfinite(m_dry)) or np.any(m_dry <= 0):
        raise InputError(
            f"{root}: observation_mode 'sensors' needs each run's dry mass m_dry > 0 kg "
            "(a run whose config the engine could not build has none)"
        )


def sensor_view(
    root: Any, frames: pl.DataFrame, runs: pl.DataFrame, train_runs: np.ndarray, model: SensorModel
) -> SensorView:
    """The sensors' view of ``frames`` under ``model`` (see the module docstring), its
    standardisation taken from the rows of ``train_runs``."""
    check_sensor_columns(root, frames, runs)
    true = frames.select(SENSOR_NAMES).to_numpy().astype(np.float64)
    run = frames["run"].to_numpy().astype(np.int64)
    seg = frames["segment"].to_numpy().astype(np.int64)
    observed = np.empty_like(true)
    starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], seg.size], strict=True):
        observed[a:b] = observe_rows(true[a:b], model, (int(run[a]), int(seg[a])))
    dry = dict(zip(runs["run"].to_list(), runs["m_dry"].to_list(), strict=True))
    m_dry = np.array([dry[r] for r in run.tolist()], dtype=np.float64)
    values = np.column_stack([observed, m_dry])
    train = values[np.isin(run, train_runs)]
    if train.shape[0] == 0:
        raise InputError(f"{root}: no training rows to standardise the sensors on")
    mean = train.mean(axis=0)
    std = train.std(axis=0)
    # A channel constant over the training rows (a flag never raised) reads as its offset.
    std = np.where(std > 1e-12 * np.maximum(1.0, np.abs(mean)), std, 1.0)
    standardised = ((values - mean) / std).astype(np.float32)
    return SensorView(model, values, mean, std, standardised)


__all__ = ["SENSOR_INPUTS", "SensorView", "check_sensor_columns", "sensor_view"]
