"""AC-MLP-WM (paper Eq. 13-15): latest masked state plus the flattened chunk, two hidden
layers of 128, three heads; continuous changes are accumulated from z_t. A lookahead
diagnostic: even its first prediction sees the whole chunk."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from rmi_learn.data.schema import HORIZON
from rmi_learn.world_models.common import N_FRIC, N_OBS, N_U, N_Z, WorldModel, last_z


class ACMLPWM(WorldModel):
    """Lookahead MLP world model for a fixed horizon."""

    kind = "ac-mlp"

    def __init__(self, horizon: int = HORIZON, hidden: int = 128, state_groups: str = "ALL"):
        super().__init__(state_groups)
        self.horizon, self.hidden = horizon, hidden
        self.fixed_horizon = horizon
        self.body = nn.Sequential(
            nn.Linear(2 * N_OBS + horizon * N_U, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
        )
        self.head_z = nn.Linear(hidden, horizon * N_Z)
        self.head_c = nn.Linear(hidden, horizon)
        self.head_f = nn.Linear(hidden, horizon * N_FRIC)
        nn.init.normal_(self.head_z.weight, std=1e-3)
        nn.init.zeros_(self.head_z.bias)

    def config(self) -> dict[str, Any]:
        return {**super().config(), "horizon": self.horizon, "hidden": self.hidden}

    def forward(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor, **_: object
    ) -> dict[str, torch.Tensor]:
        h = self.check_horizon(actions)
        hist, hist_mask = self.prepare(hist, hist_mask)
        n = hist.shape[0]
        x = torch.cat([hist[:, -1], hist_mask[:, -1], actions.reshape(n, -1)], dim=-1)
        feat = self.body(x)
        dz = self.head_z(feat).view(n, h, N_Z) * self.delta_scale
        return {
            "z": last_z(hist).unsqueeze(1) + torch.cumsum(dz, dim=1),
            "contact_logit": self.head_c(feat),
            "friction_logit": self.head_f(feat).view(n, h, N_FRIC),
        }
