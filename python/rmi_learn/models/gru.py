"""AC-GRU-WM and State-GRU-WM (paper Eq. 9-12).

A 2-layer GRU (width 128) encodes the history [y, m]; a 2-layer GRU decoder (GRU cells)
starts from its final hidden state and steps through the horizon. Decoder input at step tau:
[y_hat_{t+tau-1}, m_hat_{t+tau-1}, E_u(u_{t+tau-1})] (State-GRU-WM drops E_u). D_z predicts the
change of the standardised continuous state, accumulated from z_t; separate heads give the
contact and friction logits. The first step's input is the latest observation and its mask;
later inputs are the model's own predictions (contact probability, friction probabilities)
marked valid, or, with teacher forcing, the ground truth with its mask.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from rmi_learn.models.common import (
    N_FRIC,
    N_OBS,
    N_U,
    N_Z,
    WorldModel,
    assemble_obs,
    last_z,
)


class GRUWorldModel(WorldModel):
    """Recurrent world model; ``action_conditioned=False`` gives State-GRU-WM."""

    recurrent = True
    # Chunks scored for one history share its encoding: the encoder runs once per history.
    shares_history = True

    def __init__(
        self,
        action_conditioned: bool = True,
        hidden: int = 128,
        layers: int = 2,
        u_embed: int = 64,
        state_groups: str = "ALL",
    ) -> None:
        super().__init__(state_groups)
        self.action_conditioned = action_conditioned
        self.kind = "ac-gru" if action_conditioned else "state-gru"
        self.hidden, self.layers, self.u_embed = hidden, layers, u_embed
        self.encoder = nn.GRU(2 * N_OBS, hidden, layers, batch_first=True)
        d_in = 2 * N_OBS
        if action_conditioned:
            self.E_u = nn.Sequential(
                nn.Linear(N_U, u_embed), nn.ReLU(), nn.Linear(u_embed, u_embed)
            )
            d_in += u_embed
        # The decoder steps one command at a time: a stack of GRU cells (same equations as a
        # multi-layer nn.GRU, without its per-call sequence overhead).
        self.decoder = nn.ModuleList(
            [nn.GRUCell(d_in if i == 0 else hidden, hidden) for i in range(layers)]
        )
        # One matrix for the three heads: [D_z (18) | contact (1) | friction (4)].
        self.head = nn.Linear(hidden, N_Z + 1 + N_FRIC)
        # Start as the persistence forecast: small residuals.
        with torch.no_grad():
            self.head.weight[:N_Z].normal_(std=1e-3)
            self.head.bias[:N_Z].zero_()

    def config(self) -> dict[str, Any]:
        return {
            **super().config(),
            "hidden": self.hidden,
            "layers": self.layers,
            "u_embed": self.u_embed,
        }

    def forward(
        self,
        hist: torch.Tensor,
        hist_mask: torch.Tensor,
        actions: torch.Tensor,
        teacher: dict[str, torch.Tensor] | None = None,
        tf_prob: float = 0.0,
    ) -> dict[str, torch.Tensor]:
        """See :mod:`rmi_learn.models.common`; ``teacher`` is a batch with ``target``,
        ``target_mask``, ``target_c``, ``target_r`` used with probability ``tf_prob``."""
        h_len = self.check_horizon(actions)
        hist, hist_mask = self.prepare(hist, hist_mask)
        n, b = actions.shape[0], hist.shape[0]
        if n % b:
            raise ValueError(f"{n} action chunks do not split evenly over {b} histories")
        rep = n // b
        keep = self.obs_keep
        _, h_enc = self.encoder(torch.cat([hist, hist_mask], dim=-1))
        h = list(h_enc.repeat_interleave(rep, dim=1).unbind(0))
        y, m = hist[:, -1].repeat_interleave(rep, 0), hist_mask[:, -1].repeat_interleave(rep, 0)
        z = last_z(hist).repeat_interleave(rep, 0)
        e = self.E_u(actions) if self.action_conditioned else None
        ones = keep.expand(n, -1)
        use_tf = teacher is not None and tf_prob > 0.0 and self.training
        zs, cs, fs = [], [], []
        for tau in range(h_len):
            x = torch.cat([y, m] if e is None else [y, m, e[:, tau]], dim=-1)
            for i, cell in enumerate(self.decoder):
                h[i] = cell(x, h[i])
                x = h[i]
            dz, c_logit, f_logit = self.head(x).split((N_Z, 1, N_FRIC), dim=-1)
            c_logit = c_logit[:, 0]
            z = z + dz
            zs.append(z)
            cs.append(c_logit)
            fs.append(f_logit)
            if tau == h_len - 1:
                break
            y = assemble_obs(z, torch.sigmoid(c_logit), torch.softmax(f_logit, -1)) * keep
            m = ones
            if use_tf:
                assert teacher is not None
                pick = torch.rand(n, 1, device=z.device) < tf_prob
                tz = teacher["target"][:, tau]
                tm = teacher["target_mask"][:, tau]
                tc = teacher["target_c"][:, tau].to(z.dtype)
                tr = F.one_hot(teacher["target_r"][:, tau].long(), N_FRIC).to(z.dtype)
                y_true = assemble_obs(tz, tc, tr) * keep
                m_true = assemble_obs(tm, torch.ones_like(tc), torch.ones_like(tr)) * keep
                y = torch.where(pick, y_true, y)
                m = torch.where(pick, m_true, m)
                # Accumulate from the true state where it is defined.
                z = torch.where(pick & (tm > 0), tz, z)
        return {
            "z": torch.stack(zs, 1),
            "contact_logit": torch.stack(cs, 1),
            "friction_logit": torch.stack(fs, 1),
        }


class ACGRUWM(GRUWorldModel):
    """AC-GRU-WM: one command per decoder step through E_u."""

    kind = "ac-gru"

    def __init__(self, **kw: Any) -> None:
        kw.pop("action_conditioned", None)
        super().__init__(action_conditioned=True, **kw)


class StateGRUWM(GRUWorldModel):
    """State-GRU-WM: the same network without E_u (ignores the actions)."""

    kind = "state-gru"

    def __init__(self, **kw: Any) -> None:
        kw.pop("action_conditioned", None)
        super().__init__(action_conditioned=False, **kw)
