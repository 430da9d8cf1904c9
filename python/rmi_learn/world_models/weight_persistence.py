"""The sensors mode's persistence: the retained water read off the wrist load, carried over
the horizon.

What a scale in the wrist tells (:mod:`rmi_learn.sensing.weight`): carried in the air, the
vertical wrist load is minus the weight of the sponge and all the water it carries, so the
water in the pores is -W_z / g minus the dry mass and the expelled water that has not dripped
off (a constant ``offset``, fitted on the training runs' squeeze rows). The reading is the mean
of the history's rows, as one row carries the sensor's noise (0.06 N is 6 g). It forecasts
the water only; the other channels stay at the training mean. A learned sensor-mode model
has to beat it, as a y_t model has to beat the Baseline.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from rmi_learn.data.dataset.sensor_view import SENSOR_INPUTS
from rmi_learn.sensing import STANDARD_GRAVITY, SensorModel
from rmi_learn.world_models.common import N_FRIC, N_Z, WATER, WorldModel

_WZ = SENSOR_INPUTS.index("W_z")
_DRY = SENSOR_INPUTS.index("m_dry")

#: The fields of a weight reading: how the sensor inputs W_z (N) and m_dry (kg) and y_t's
#: water M_L (kg) are standardised (mean, standard deviation each).
WEIGHT_READING = ("wz_mean", "wz_std", "dry_mean", "dry_std", "water_mean", "water_std")


def weight_reading(ds: Any, sensors: SensorModel) -> tuple[float, ...]:
    """The :data:`WEIGHT_READING` of ``ds`` under ``sensors``: its sensor view's
    standardisation of W_z and m_dry and its statistics' of M_L."""
    view = ds.sensor_view(sensors)
    return tuple(
        float(v)
        for v in (
            view.mean[_WZ],
            view.std[_WZ],
            view.mean[_DRY],
            view.std[_DRY],
            ds.stats.z_mean[WATER],
            ds.stats.z_std[WATER],
        )
    )


def weight_water(hist: torch.Tensor, reading: Sequence[float], offset: float = 0.0) -> torch.Tensor:
    """The standardised water the wrist load's weight tells of each history (B, L, C) of
    standardised ``SENSOR_INPUTS``, (B,): the mean vertical load over the history, over g,
    minus the dry mass and the carried water ``offset`` (kg)."""
    wz_mean, wz_std, dry_mean, dry_std, water_mean, water_std = reading
    w_z = hist[:, :, _WZ].mean(dim=1) * wz_std + wz_mean
    m_dry = hist[:, -1, _DRY] * dry_std + dry_mean
    return (-w_z / STANDARD_GRAVITY - m_dry - offset - water_mean) / water_std


class WeightPersistenceWM(WorldModel):
    """Water from the wrist load's weight, persisted (see the module docstring):
    ``reading`` is a :data:`WEIGHT_READING`, ``offset`` (kg) the carried water."""

    kind = "weight-persistence"
    trainable = False
    takes_sensors = True

    def __init__(self, reading: Sequence[float], offset: float = 0.0) -> None:
        super().__init__("ALL", "sensors")
        self.reading = tuple(float(v) for v in reading)
        self.offset = float(offset)

    @classmethod
    def from_dataset(cls, ds: Any, sensors: SensorModel) -> WeightPersistenceWM:
        """Fitted on ``ds``'s training runs: the offset is the mean over their squeeze rows
        of the weight estimate minus M_L, under ``sensors``."""
        view = ds.sensor_view(sensors)
        rows = np.isin(ds.row_run, ds.split_runs("train")) & (ds.row_phase == "squeeze")
        water = ds.frames["M_L"].to_numpy()[rows]
        weight = -view.values[rows, _WZ] / STANDARD_GRAVITY - view.values[rows, _DRY]
        offset = float(np.mean(weight - water)) if rows.any() else 0.0
        return cls(weight_reading(ds, sensors), offset)

    def estimate_state(self, hist: torch.Tensor, hist_mask: torch.Tensor) -> torch.Tensor:
        """z_t (B, 18) standardised: the water read off the wrist load, the rest zero."""
        z = hist.new_zeros(hist.shape[0], N_Z)
        z[:, WATER] = weight_water(hist, self.reading, self.offset)
        return z

    def forward(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor, **_: object
    ) -> dict[str, torch.Tensor]:
        h = self.check_horizon(actions)
        z = self.estimate_state(hist, hist_mask).unsqueeze(1).expand(-1, h, -1)
        n = hist.shape[0]
        return {
            "z": z.contiguous(),
            "contact_logit": hist.new_zeros(n, h),
            "friction_logit": hist.new_zeros(n, h, N_FRIC),
        }


__all__ = ["WEIGHT_READING", "WeightPersistenceWM", "weight_reading", "weight_water"]
