"""Reference forecasts without learning: persistence (carry the latest state, contact
indicator and friction label over the horizon) and the setpoint readout (persistence, with the
measured force read off the commanded setpoints)."""

from __future__ import annotations

from typing import Any

import torch

from rmi_learn.data.schema import CONTACT_INDEX, FRICTION_SLICE
from rmi_learn.world_models.common import FORCE, WorldModel, last_z

#: Logit magnitude used to express a carried 0/1 label (probability 1 - 4.5e-5).
_CONFIDENT = 10.0


class BaselineWM(WorldModel):
    """Persistence forecast; no parameters, no training."""

    kind = "baseline"
    trainable = False

    def forward(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor, **_: object
    ) -> dict[str, torch.Tensor]:
        h = self.check_horizon(actions)
        hist, hist_mask = self.prepare(hist, hist_mask)
        z = last_z(hist).unsqueeze(1).expand(-1, h, -1)
        c = hist[:, -1, CONTACT_INDEX]
        r = hist[:, -1, FRICTION_SLICE]
        contact_logit = (2.0 * c - 1.0) * _CONFIDENT
        friction_logit = (2.0 * r - 1.0) * _CONFIDENT
        return {
            "z": z.contiguous(),
            "contact_logit": contact_logit.unsqueeze(1).expand(-1, h).contiguous(),
            "friction_logit": friction_logit.unsqueeze(1).expand(-1, h, -1).contiguous(),
        }


class SetpointReadoutWM(BaselineWM):
    """Persistence, except that the measured force after each command is the command's
    setpoint: ``F_meas(t + tau) = F_target(t + tau - 1)``. The engine's force loop tracks a
    setpoint within a control step, so this is what a model gains on force by reading the
    chunk alone; a world model's force accuracy is worth something only beyond it.

    ``u_mean``, ``u_std`` (N) standardise F_target, ``f_mean``, ``f_std`` (N) F_meas, as in
    the dataset the windows come from."""

    kind = "setpoint-readout"

    def __init__(
        self,
        u_mean: float = 0.0,
        u_std: float = 1.0,
        f_mean: float = 0.0,
        f_std: float = 1.0,
        state_groups: str = "ALL",
    ) -> None:
        super().__init__(state_groups)
        self.scale = (float(u_mean), float(u_std), float(f_mean), float(f_std))

    @classmethod
    def from_stats(cls, stats: Any) -> SetpointReadoutWM:
        """From dataset statistics (``u_mean``, ``u_std``, ``z_mean``, ``z_std``)."""
        return cls(
            float(stats.u_mean[0]),
            float(stats.u_std[0]),
            float(stats.z_mean[FORCE]),
            float(stats.z_std[FORCE]),
        )

    def config(self) -> dict[str, Any]:
        u_mean, u_std, f_mean, f_std = self.scale
        return {**super().config(), "u_mean": u_mean, "u_std": u_std, "f_mean": f_mean,
                "f_std": f_std}  # fmt: skip

    def forward(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor, **_: object
    ) -> dict[str, torch.Tensor]:
        out = super().forward(hist, hist_mask, actions)
        u_mean, u_std, f_mean, f_std = self.scale
        setpoint_n = actions[..., 0] * u_std + u_mean
        z = out["z"].clone()
        z[..., FORCE] = (setpoint_n - f_mean) / f_std
        return {**out, "z": z}
