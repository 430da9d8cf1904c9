"""Goal-conditioned temporal UNet shared by the diffusion and flow-matching policies.

The network maps a noisy (or interpolated) action chunk ``x`` of shape ``(N, H_pi, 2)`` in
standardised action units, a generative time ``t`` (diffusion step 0..49, or flow time
multiplied by 1000) and the condition (history, validity mask and goal) to a chunk of the
same shape: the clean chunk for x0-prediction diffusion, the velocity ``A - eps`` for
rectified flow.

Layout (Diffusion Policy style, Chi et al. 2023): channels 64/128/256, kernel 5, every
residual block is conv -> GroupNorm(8) -> Mish, FiLM from the condition, conv -> GroupNorm ->
Mish, plus a 1x1 residual convolution when the channel count changes. The down path stores
skips before stride-2 downsampling; the up path concatenates them. The condition vector is
``[time embedding, GRU summary of (history, mask), goal MLP]`` and is fed to every block.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import cast

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class UNetConfig:
    """Hyper-parameters of :class:`PolicyUNet` (defaults are the paper's)."""

    action_dim: int = 1  # schema.CONTROL_ACTIONS: the force setpoint
    horizon: int = 32
    obs_dim: int = 23
    channels: tuple[int, ...] = (64, 128, 256)
    kernel_size: int = 5
    n_groups: int = 8
    time_embed_dim: int = 128
    gru_hidden: int = 64
    goal_dim: int = 2
    goal_hidden: int = 64

    def to_dict(self) -> dict[str, object]:
        """JSON-friendly dict (tuples become lists)."""
        d = asdict(self)
        d["channels"] = list(self.channels)
        return d

    @classmethod
    def from_dict(cls, d: object) -> UNetConfig:
        """Inverse of :meth:`to_dict`. A value that is not a whole number >= 1 (``channels``:
        a non-empty list of them) and an unknown key raise ValueError naming the field:
        the dict comes from a run's ``config.json``."""
        if not isinstance(d, Mapping):
            raise ValueError(f"unet must be an object of UNet fields, got {d!r}")
        unknown = sorted(set(d) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unet: unknown field(s) {unknown}")
        kw: dict[str, object] = {}
        for name, value in d.items():
            if name == "channels":
                ok = isinstance(value, (list, tuple)) and bool(value) and all(map(_whole, value))
                want = "a non-empty list of whole numbers >= 1"
            else:
                ok, want = _whole(value), "a whole number >= 1"
            if not ok:
                raise ValueError(f"unet field {name!r} must be {want}, got {value!r}")
            kw[name] = tuple(value) if name == "channels" else value  # type: ignore[arg-type]
        return cls(**kw)  # type: ignore[arg-type]


def _whole(value: object) -> bool:
    """Whether ``value`` is a whole number >= 1 (not a bool)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def sinusoidal_embedding(t: Tensor, dim: int) -> Tensor:
    """Sinusoidal embedding of a (N,) tensor of times in *step units* -> (N, dim).

    Built for integer diffusion steps (frequencies 1 .. 1/10000 per step): feed diffusion
    step indices directly and flow time ``t in [0, 1]`` multiplied by 1000, otherwise the
    whole unit interval falls inside one slow period and the network cannot resolve it.
    """
    if dim % 2 != 0:
        raise ValueError(f"embedding dim must be even, got {dim}")
    half = dim // 2
    scale = math.log(10000.0) / max(half - 1, 1)
    freqs = torch.exp(torch.arange(half, device=t.device, dtype=torch.float32) * -scale)
    args = t.to(torch.float32)[:, None] * freqs[None, :]
    return torch.cat([args.sin(), args.cos()], dim=-1)


class Conv1dBlock(nn.Module):
    """Conv1d(k) -> GroupNorm -> Mish on (N, C, T)."""

    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int) -> None:
        super().__init__()
        self.block = nn.Sequential(
            nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2),
            nn.GroupNorm(groups, c_out),
            nn.Mish(),
        )

    def forward(self, x: Tensor) -> Tensor:
        out: Tensor = self.block(x)
        return out


class FiLMResidualBlock(nn.Module):
    """Residual block with FiLM conditioning: scale and bias per channel from ``cond``."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel: int, groups: int) -> None:
        super().__init__()
        self.block1 = Conv1dBlock(c_in, c_out, kernel, groups)
        self.block2 = Conv1dBlock(c_out, c_out, kernel, groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.residual = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()
        self.c_out = c_out

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        h = self.block1(x)
        scale, bias = self.film(cond).unsqueeze(-1).chunk(2, dim=1)
        h = scale * h + bias
        h = self.block2(h)
        out: Tensor = h + self.residual(x)
        return out


class PolicyUNet(nn.Module):
    """Temporal UNet eps/x0/velocity network, conditioned on history, mask, goal and time.

    ``forward(x, t, hist, hist_mask, goal)``: ``x`` (N, H, action_dim) standardised actions,
    ``t`` (N,) time in step units (see :func:`sinusoidal_embedding`), ``hist`` and
    ``hist_mask`` (N, L, obs_dim), ``goal`` (N, 2) standardised goal. Returns (N, H,
    action_dim). Use :meth:`encode_condition` + :meth:`denoise` to reuse the history/goal
    encoding across sampling steps.
    """

    def __init__(self, config: UNetConfig | None = None) -> None:
        super().__init__()
        cfg = config or UNetConfig()
        g = cfg.n_groups
        if not cfg.channels or any(c < g or c % g for c in cfg.channels):
            # GroupNorm splits each block's channels into n_groups groups.
            raise ValueError(f"channels {list(cfg.channels)} must be positive multiples of {g}")
        if cfg.horizon % (2 ** (len(cfg.channels) - 1)) != 0:
            raise ValueError(
                f"horizon {cfg.horizon} must be divisible by {2 ** (len(cfg.channels) - 1)}"
            )
        self.config = cfg
        te = cfg.time_embed_dim
        self.time_mlp = nn.Sequential(nn.Linear(te, 4 * te), nn.Mish(), nn.Linear(4 * te, te))
        self.gru = nn.GRU(2 * cfg.obs_dim, cfg.gru_hidden, batch_first=True)
        self.goal_mlp = nn.Sequential(
            nn.Linear(cfg.goal_dim, cfg.goal_hidden),
            nn.Mish(),
            nn.Linear(cfg.goal_hidden, cfg.goal_hidden),
        )
        cond_dim = te + cfg.gru_hidden + cfg.goal_hidden
        k, g = cfg.kernel_size, cfg.n_groups
        chans = list(cfg.channels)
        ins = [cfg.action_dim, *chans[:-1]]

        self.down = nn.ModuleList()
        for i, (ci, co) in enumerate(zip(ins, chans, strict=True)):
            last = i == len(chans) - 1
            self.down.append(
                nn.ModuleList(
                    [
                        FiLMResidualBlock(ci, co, cond_dim, k, g),
                        FiLMResidualBlock(co, co, cond_dim, k, g),
                        nn.Conv1d(co, co, 3, stride=2, padding=1) if not last else nn.Identity(),
                    ]
                )
            )
        mid = chans[-1]
        self.mid = nn.ModuleList(
            [
                FiLMResidualBlock(mid, mid, cond_dim, k, g),
                FiLMResidualBlock(mid, mid, cond_dim, k, g),
            ]
        )
        self.up = nn.ModuleList()
        rev = list(reversed(chans))
        for i in range(len(rev) - 1):
            co, ci = rev[i + 1], rev[i]
            self.up.append(
                nn.ModuleList(
                    [
                        FiLMResidualBlock(2 * ci, co, cond_dim, k, g),
                        FiLMResidualBlock(co, co, cond_dim, k, g),
                        nn.ConvTranspose1d(co, co, 4, stride=2, padding=1),
                    ]
                )
            )
        self.final = nn.Sequential(
            Conv1dBlock(chans[0], chans[0], k, g), nn.Conv1d(chans[0], cfg.action_dim, 1)
        )

    def encode_condition(self, hist: Tensor, hist_mask: Tensor, goal: Tensor) -> Tensor:
        """History/mask GRU summary and goal MLP, concatenated: (N, gru_hidden + goal_hidden)."""
        _, h = self.gru(torch.cat([hist, hist_mask], dim=-1))
        return torch.cat([h[-1], self.goal_mlp(goal)], dim=-1)

    def denoise(self, x: Tensor, t: Tensor, obs_cond: Tensor) -> Tensor:
        """Network output for chunk ``x`` (N, H, A) at step-unit time ``t`` (N,) given the
        encoded condition from :meth:`encode_condition`."""
        temb = self.time_mlp(sinusoidal_embedding(t, self.config.time_embed_dim))
        cond = torch.cat([temb, obs_cond], dim=-1)
        h = x.transpose(1, 2)
        skips: list[Tensor] = []
        for lv in self.down:
            level = cast(nn.ModuleList, lv)
            h = level[1](level[0](h, cond), cond)
            skips.append(h)
            h = level[2](h)
        for block in self.mid:
            h = block(h, cond)
        for lv in self.up:
            level = cast(nn.ModuleList, lv)
            h = torch.cat([h, skips.pop()], dim=1)
            h = level[1](level[0](h, cond), cond)
            h = level[2](h)
        out: Tensor = self.final(h).transpose(1, 2)
        return out

    def forward(
        self, x: Tensor, t: Tensor, hist: Tensor, hist_mask: Tensor, goal: Tensor
    ) -> Tensor:
        return self.denoise(x, t, self.encode_condition(hist, hist_mask, goal))


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


class ChunkSampler:
    """Sampling entry shared by the training objectives: draw the noise, encode the
    condition once, and let the objective's ``sample_from_condition`` integrate."""

    def sample_from_condition(self, model: PolicyUNet, obs_cond: Tensor, noise: Tensor) -> Tensor:
        raise NotImplementedError

    @torch.no_grad()
    def sample(
        self,
        model: PolicyUNet,
        hist: Tensor,
        hist_mask: Tensor,
        goal: Tensor,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """One standardised chunk (N, H, 2) per condition row."""
        cfg = model.config
        noise = torch.randn((hist.shape[0], cfg.horizon, cfg.action_dim), generator=generator)
        obs_cond = model.encode_condition(hist, hist_mask, goal)
        return self.sample_from_condition(model, obs_cond, noise.to(hist.device))
