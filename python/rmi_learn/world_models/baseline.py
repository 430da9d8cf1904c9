"""Baseline: carry the latest state, contact indicator and friction label over the horizon."""

from __future__ import annotations

import torch

from rmi_learn.data.schema import CONTACT_INDEX, FRICTION_SLICE
from rmi_learn.world_models.common import WorldModel, last_z

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
