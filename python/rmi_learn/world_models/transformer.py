"""Causal Transformer world model W_T (paper Sec. IV-C, the ranking scorer).

Encoder: the L history tokens [y, m] -> width 256 plus learned positions, 3 pre-LN layers.
Decoder: one token per command u_{t+tau-1} (plus learned positions), 4 pre-LN layers with a
causal self-attention mask and cross-attention to the encoded history, so the forecast of
step tau sees the history and the commands u_t..u_{t+tau-1} only. Both stacks end with a
LayerNorm (pre-LN blocks leave their output unnormalised; PyTorch adds none by default).
Heads predict the change of the standardised continuous state (accumulated from z_t), the
contact logit and the friction logits. Because of the causal mask, a chunk of any length
H <= max_horizon gives exactly the first H steps of a longer chunk's forecast.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from torch import nn

from rmi_learn.data.schema import HISTORY, HORIZON
from rmi_learn.world_models.common import (
    N_FRIC,
    N_OBS,
    N_U,
    N_Z,
    WorldModel,
    constructor_defaults,
    last_z,
)


class TransformerWM(WorldModel):
    """Encoder-decoder Transformer, causal in the actions."""

    kind = "transformer"
    #: ``forward`` accepts B histories with B * M action chunks (M consecutive chunks per
    #: history), so that scoring candidates does not repeat the history encoding.
    shares_history = True
    causal: torch.Tensor

    def __init__(
        self,
        d_model: int = 256,
        nhead: int = 8,
        enc_layers: int = 3,
        dec_layers: int = 4,
        ff: int = 512,
        dropout: float = 0.1,
        history: int = HISTORY,
        max_horizon: int = HORIZON,
        state_groups: str = "ALL",
    ) -> None:
        super().__init__(state_groups)
        self.d_model, self.nhead, self.ff, self.dropout = d_model, nhead, ff, dropout
        self.enc_layers, self.dec_layers = enc_layers, dec_layers
        self.history, self.max_horizon = history, max_horizon
        self.in_proj = nn.Linear(2 * N_OBS, d_model)
        self.enc_pos = nn.Parameter(torch.randn(1, history, d_model) * 0.02)
        self.u_proj = nn.Linear(N_U, d_model)
        self.dec_pos = nn.Parameter(torch.randn(1, max_horizon, d_model) * 0.02)
        enc = nn.TransformerEncoderLayer(
            d_model, nhead, ff, dropout, batch_first=True, norm_first=True
        )
        dec = nn.TransformerDecoderLayer(
            d_model, nhead, ff, dropout, batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(
            enc, enc_layers, norm=nn.LayerNorm(d_model), enable_nested_tensor=False
        )
        self.decoder = nn.TransformerDecoder(dec, dec_layers, norm=nn.LayerNorm(d_model))
        self.head_z = nn.Linear(d_model, N_Z)
        self.head_c = nn.Linear(d_model, 1)
        self.head_f = nn.Linear(d_model, N_FRIC)
        nn.init.normal_(self.head_z.weight, std=1e-3)
        nn.init.zeros_(self.head_z.bias)
        causal = torch.triu(torch.full((max_horizon, max_horizon), float("-inf")), diagonal=1)
        self.register_buffer("causal", causal, persistent=False)

    @classmethod
    def check_arguments(cls, args: Mapping[str, Any]) -> None:
        """The checks of every model, then the attention's: ``dropout`` a probability and
        ``d_model`` split evenly over the ``nhead`` heads."""
        super().check_arguments(args)
        a = {**constructor_defaults(cls), **args}
        if not 0.0 <= a["dropout"] <= 1.0:
            raise ValueError(f"{cls.kind}: dropout must be in [0, 1], got {a['dropout']!r}")
        if a["d_model"] % a["nhead"]:
            raise ValueError(
                f"{cls.kind}: d_model must be a multiple of nhead, got d_model={a['d_model']} "
                f"and nhead={a['nhead']}"
            )

    def config(self) -> dict[str, Any]:
        return {
            **super().config(),
            "d_model": self.d_model,
            "nhead": self.nhead,
            "enc_layers": self.enc_layers,
            "dec_layers": self.dec_layers,
            "ff": self.ff,
            "dropout": self.dropout,
            "history": self.history,
            "max_horizon": self.max_horizon,
        }

    def forward(
        self, hist: torch.Tensor, hist_mask: torch.Tensor, actions: torch.Tensor, **_: object
    ) -> dict[str, torch.Tensor]:
        h = self.check_horizon(actions)
        hist, hist_mask = self.prepare(hist, hist_mask)
        L = hist.shape[1]
        if L > self.history:
            raise ValueError(f"history {L} exceeds the model's {self.history}")
        n, b = actions.shape[0], hist.shape[0]
        if n % b:
            raise ValueError(f"{n} action chunks do not split evenly over {b} histories")
        x = self.in_proj(torch.cat([hist, hist_mask], dim=-1)) + self.enc_pos[:, -L:]
        # Chunks scored for one history share its encoding (``shares_history``): the encoder
        # runs once per history, not once per candidate chunk.
        memory = self.encoder(x).repeat_interleave(n // b, dim=0)
        q = self.u_proj(actions) + self.dec_pos[:, :h]
        o = self.decoder(q, memory, tgt_mask=self.causal[:h, :h], tgt_is_causal=True)
        z0 = last_z(hist).repeat_interleave(n // b, dim=0)
        return {
            "z": z0.unsqueeze(1) + torch.cumsum(self.head_z(o) * self.delta_scale, dim=1),
            "contact_logit": self.head_c(o)[..., 0],
            "friction_logit": self.head_f(o).view(n, h, N_FRIC),
        }
