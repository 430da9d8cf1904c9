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

from typing import Any

import numpy as np
import torch

from rmi_learn.data.dataset.sensor_view import SENSOR_INPUTS
from rmi_learn.sensing import STANDARD_GRAVITY, SensorModel
from rmi_learn.world_models.common import N_FRIC, N_Z, WATER, WorldModel

_WZ = SENSOR_INPUTS.index("W_z")
_DRY = SENSOR_INPUTS.index("m_dry")


class WeightPersistenceWM(WorldModel):
    """Water from the wrist load's weight, persisted (see the module docstring).

    ``water_mean``, ``water_std`` (kg) standardise M_L; ``wz_mean``, ``wz_std`` (N) and
    ``dry_mean``, ``dry_std`` (kg) are the sensor inputs' standardisation; ``offset`` (kg)
    the carried water."""

    kind = "weight-persistence"
    trainable = False
    takes_sensors = True

    def __init__(
        self,
        water_mean: float = 0.0,
        water_std: float = 1.0,
        wz_mean: float = 0.0,
        wz_std: float = 1.0,
        dry_mean: float = 0.0,
        dry_std: float = 1.0,
        offset: float = 0.0,
    ) -> None:
        super().__init__("ALL", "sensors")
        self.scale = tuple(
            float(v) for v in (water_mean, water_std, wz_mean, wz_std, dry_mean, dry_std)
        )
        self.offset = float(offset)

    @classmethod
    def from_dataset(cls, ds: Any, sensors: SensorModel) -> WeightPersistenceWM:
        """Fitted on ``ds``'s training runs: the offset is the mean over their squeeze rows
        of the weight estimate minus M_L, under ``sensors``."""
        view = ds.sensor_view(sensors)
        rows = np.isin(ds.row_run, ds.split_runs("train")) & (
            ds.frames["phase"].to_numpy().astype(str) == "squeeze"
        )
        water = ds.frames["M_L"].to_numpy()[rows]
        weight = -view.values[rows, _WZ] / STANDARD_GRAVITY - view.values[rows, _DRY]
        offset = float(np.mean(weight - water)) if rows.any() else 0.0
        return cls(
            float(ds.stats.z_mean[WATER]),
            float(ds.stats.z_std[WATER]),
            float(view.mean[_WZ]),
            float(view.std[_WZ]),
            float(view.mean[_DRY]),
            float(view.std[_DRY]),
            offset,
        )

    def estimate_state(self, hist: torch.Tensor, hist_mask: torch.Tensor) -> torch.Tensor:
        """z_t (B, 18) standardised: the water read off the wrist load, the rest zero."""
        water_mean, water_std, wz_mean, wz_std, dry_mean, dry_std = self.scale
        w_z = hist[:, :, _WZ].mean(dim=1) * wz_std + wz_mean
        m_dry = hist[:, -1, _DRY] * dry_std + dry_mean
        water = -w_z / STANDARD_GRAVITY - m_dry - self.offset
        z = hist.new_zeros(hist.shape[0], N_Z)
        z[:, WATER] = (water - water_mean) / water_std
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


__all__ = ["WeightPersistenceWM"]
