"""Linear-ARX (paper Sec. IV-B): ridge regression (lambda = 1e-2) of the standardised
residuals z_{t+tau} - z_t, the contact indicator and the friction one-hot over the horizon on
the flattened history [Y_t, M_t] and action chunk A_t, fitted in closed form on training
windows whose targets are complete (every target_mask entry is 1). Inputs and targets are
centred, so the intercept is not penalised. Contact and friction scores are clipped to
[1e-4, 1 - 1e-4] and turned into logits / log-probabilities.

By default every forecast step sees the whole chunk (the paper's lookahead model): the
forecast at step k also regresses on the setpoints after k, which cannot have caused it but
correlate with it in the data. ``causal=True`` fits each step on the history and the
setpoints up to and including its own only (one ridge solve per step). The terminal step is
the same fit either way; the intermediate steps differ, which matters to a controller that
asks for the water at a goal time inside the chunk (re-planning with a shrinking horizon)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from rmi_learn.data.schema import HISTORY, HORIZON
from rmi_learn.world_models.common import N_FRIC, N_OBS, N_U, N_Z, WorldModel, last_z


class LinearARX(WorldModel):
    """Closed-form lookahead linear model for a fixed history and horizon."""

    kind = "arx"
    trainable = False
    W: torch.Tensor
    x_mean: torch.Tensor
    y_mean: torch.Tensor
    n_fit: torch.Tensor

    def __init__(
        self,
        history: int = HISTORY,
        horizon: int = HORIZON,
        ridge: float = 1e-2,
        state_groups: str = "ALL",
        causal: bool = False,
    ):
        super().__init__(state_groups)
        self.history, self.horizon, self.ridge = history, horizon, ridge
        self.causal = bool(causal)
        self.fixed_horizon = horizon
        p = history * 2 * N_OBS + horizon * N_U
        q = horizon * (N_Z + 1 + N_FRIC)
        self.register_buffer("W", torch.zeros(p, q))
        self.register_buffer("x_mean", torch.zeros(p))
        self.register_buffer("y_mean", torch.zeros(q))
        self.register_buffer("n_fit", torch.zeros((), dtype=torch.int64))

    def config(self) -> dict[str, Any]:
        return {
            **super().config(),
            "history": self.history,
            "horizon": self.horizon,
            "ridge": self.ridge,
            "causal": self.causal,
        }

    def features(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor
    ) -> torch.Tensor:
        """Flattened regressors (N, L*46 + H*2)."""
        hist, hist_mask = self.prepare(hist, hist_mask)
        n = hist.shape[0]
        return torch.cat(
            [hist.reshape(n, -1), hist_mask.reshape(n, -1), actions.reshape(n, -1)], dim=-1
        )

    def targets(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Regression targets (N, H*(18+1+4)): residuals, contact, friction one-hot."""
        n = batch["hist"].shape[0]
        res = batch["target"] - last_z(batch["hist"]).unsqueeze(1)
        c = batch["target_c"].to(res.dtype).unsqueeze(-1)
        r = F.one_hot(batch["target_r"].long(), N_FRIC).to(res.dtype)
        return torch.cat([res, c, r], dim=-1).reshape(n, -1)

    @torch.no_grad()
    def fit(self, data: Any, batch_size: int = 1024) -> int:
        """Fit on every window of ``data`` (``batch(indices)``) with complete targets.
        Returns the number of windows used; raises if there are none."""
        p, q = self.W.shape
        xtx = torch.zeros(p, p, dtype=torch.float64)
        xty = torch.zeros(p, q, dtype=torch.float64)
        sx = torch.zeros(p, dtype=torch.float64)
        sy = torch.zeros(q, dtype=torch.float64)
        n = 0
        for s in range(0, len(data), batch_size):
            b = data.batch(np.arange(s, min(s + batch_size, len(data))))
            full = b["target_mask"].reshape(len(b["target_mask"]), -1).min(dim=1).values > 0
            if not bool(full.any()):
                continue
            b = {k: v[full] for k, v in b.items() if isinstance(v, torch.Tensor)}
            x = self.features(b["hist"], b["hist_mask"], b["actions"]).double()
            y = self.targets(b).double()
            xtx += x.T @ x
            xty += x.T @ y
            sx += x.sum(0)
            sy += y.sum(0)
            n += x.shape[0]
        if n == 0:
            raise ValueError("Linear-ARX: no training window has a complete target")
        mx, my = sx / n, sy / n
        cxx = xtx - n * torch.outer(mx, mx)
        cxy = xty - n * torch.outer(mx, my)
        a = cxx + self.ridge * torch.eye(p, dtype=torch.float64)
        w = self._solve_causal(a, cxy) if self.causal else torch.linalg.solve(a, cxy)
        self.W.copy_(w.float())
        self.x_mean.copy_(mx.float())
        self.y_mean.copy_(my.float())
        self.n_fit.fill_(n)
        return n

    def _solve_causal(self, a: torch.Tensor, cxy: torch.Tensor) -> torch.Tensor:
        """Per forecast step k, the ridge solution on the history and setpoints 0..k only;
        the rows of later setpoints are zero."""
        p, q = cxy.shape
        per_step = q // self.horizon
        n_hist = p - self.horizon * N_U
        w = torch.zeros(p, q, dtype=torch.float64)
        for k in range(self.horizon):
            rows = n_hist + (k + 1) * N_U
            cols = slice(k * per_step, (k + 1) * per_step)
            w[:rows, cols] = torch.linalg.solve(a[:rows, :rows], cxy[:rows, cols])
        return w

    def forward(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor, **_: object
    ) -> dict[str, torch.Tensor]:
        h = self.check_horizon(actions)
        n = hist.shape[0]
        x = self.features(hist, hist_mask, actions)
        y = ((x - self.x_mean) @ self.W + self.y_mean).view(n, h, N_Z + 1 + N_FRIC)
        z = last_z(self.prepare(hist, hist_mask)[0]).unsqueeze(1) + y[..., :N_Z]
        c = y[..., N_Z].clamp(1e-4, 1 - 1e-4)
        r = y[..., N_Z + 1 :].clamp(1e-4, 1 - 1e-4)
        return {"z": z, "contact_logit": torch.logit(c), "friction_logit": torch.log(r)}
