"""The fast sampling path of a policy: the objective's sampler (DDIM or Euler) computed with
less work per call, for decisions within one 20 ms control period on a CPU.

The reference path (the objective's own ``sample_from_condition``) is kept unchanged for the
paper's tables. :class:`FastSampler` computes the same samples with less work per decision:

- everything runs under ``torch.inference_mode()`` with functional calls on the network's
  parameters (no module dispatch, no autograd bookkeeping);
- the history/goal encoding runs once per window, and the FiLM scale and bias of every
  residual block are split into a time part (computed once per sampler schedule, when the
  sampler is built) and a condition part (one matrix product per decision for all blocks
  and all steps); the K samples of a window share them by broadcasting instead of repeating
  the condition K times;
- Mish is evaluated with one exponential (``x n / (n + 2)``, ``n = e^x (e^x + 2)``) instead of
  softplus and tanh;
- the sampler update of both objectives is one ``x <- a x + b out`` per step with
  coefficients fixed when the sampler is built (DDIM with eta = 0 and explicit Euler are both
  linear in ``x`` and the network output).

Given the same noise and step count, :class:`FastSampler` returns the reference sampler's
chunks to float32 rounding (``tests/planning/test_realtime.py``). Few-step students
(:mod:`rmi_learn.policies.distill`) use the same path with 1 or 2 steps; the real-time
planner (:mod:`rmi_learn.planning.realtime`) ranks its samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from rmi_learn.policies.diffusion import DiffusionObjective, ddim_step_pairs
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.unet import (
    Conv1dBlock,
    FiLMResidualBlock,
    PolicyUNet,
    sinusoidal_embedding,
)

Objective = DiffusionObjective | FlowObjective


def mish(x: Tensor) -> Tensor:
    """Mish ``x tanh(softplus(x))`` written as ``x n / (n + 2)`` with ``n = e^x (e^x + 2)``:
    one exponential instead of three transcendental passes, equal to float32 rounding. The
    exponent is capped at 20, where the ratio is 1 in float32."""
    e = x.clamp(max=20.0).exp_()
    n = e.add(2.0).mul_(e)
    return n.div_(n + 2.0).mul_(x)


@dataclass(frozen=True)
class Schedule:
    """A sampler as data: at step ``i`` the network sees time ``times[i]`` (step units, see
    :func:`~rmi_learn.policies.unet.sinusoidal_embedding`) and the chunk is updated as
    ``x <- keep[i] * x + gain[i] * out`` with ``out`` the network output."""

    times: tuple[float, ...]
    keep: tuple[float, ...]
    gain: tuple[float, ...]

    @property
    def steps(self) -> int:
        return len(self.times)


def schedule(objective: Objective, steps: int | None = None) -> Schedule:
    """The sampler of ``objective`` with ``steps`` network evaluations (default: the
    objective's own ``n_sample_steps``) as a :class:`Schedule`.

    Diffusion (DDIM, eta = 0, x0 prediction): ``x' = sqrt(abar') x0 + sqrt(1 - abar') eps``
    with ``eps = (x - sqrt(abar) x0) / sqrt(1 - abar)``, so ``keep = sqrt((1 - abar') /
    (1 - abar))`` and ``gain = sqrt(abar') - keep sqrt(abar)``. Flow (Euler from noise at
    t = 0 to data at t = 1): ``keep = 1``, ``gain = 1 / steps``.
    """
    if isinstance(objective, DiffusionObjective):
        n = objective.n_sample_steps if steps is None else steps
        ab = objective.alpha_bar
        times, keep, gain = [], [], []
        for t, t_prev in ddim_step_pairs(objective.n_train_steps, n):
            ab_t = float(ab[t])
            ab_prev = 1.0 if t_prev < 0 else float(ab[t_prev])
            k = math.sqrt((1.0 - ab_prev) / (1.0 - ab_t))
            times.append(float(t))
            keep.append(k)
            gain.append(math.sqrt(ab_prev) - k * math.sqrt(ab_t))
        return Schedule(tuple(times), tuple(keep), tuple(gain))
    if isinstance(objective, FlowObjective):
        n = objective.n_sample_steps if steps is None else steps
        if n < 1:
            raise ValueError(f"need at least one Euler step, got {n}")
        dt = 1.0 / n
        # float32 products as in the reference sampler (t in float32, then * time_scale).
        ts = torch.tensor([i * dt for i in range(n)], dtype=torch.float32)
        flow_times = tuple(float(v) for v in (ts * objective.time_scale).tolist())
        return Schedule(flow_times, (1.0,) * n, (dt,) * n)
    raise TypeError(f"unknown objective {type(objective).__name__}")


def _block_params(block: FiLMResidualBlock) -> tuple[Tensor, ...]:
    c1 = block.block1.block
    c2 = block.block2.block
    res = block.residual
    film = block.film[1]
    return (
        c1[0].weight, c1[0].bias, c1[1].weight, c1[1].bias,
        c2[0].weight, c2[0].bias, c2[1].weight, c2[1].bias,
        film.weight, film.bias,
        res.weight if isinstance(res, nn.Conv1d) else None,
        res.bias if isinstance(res, nn.Conv1d) else None,
    )  # type: ignore[return-value]  # fmt: skip


class FastSampler:
    """The sampler of ``objective`` over ``net`` without training overhead (see the module
    docstring). ``steps`` overrides the objective's step count.

    The network's parameters are read when the sampler is built: rebuild it after changing
    the weights (the time part of the FiLM tables is cached).
    """

    def __init__(self, net: PolicyUNet, objective: Objective, steps: int | None = None) -> None:
        self.net = net.eval()
        self.objective = objective
        self.schedule = schedule(objective, steps)
        cfg = net.config
        self.groups = cfg.n_groups
        self.pad = cfg.kernel_size // 2
        blocks: list[FiLMResidualBlock] = []
        for lv in net.down:
            blocks += [lv[0], lv[1]]  # type: ignore[index]
        blocks += [net.mid[0], net.mid[1]]  # type: ignore[list-item]
        for lv in net.up:
            blocks += [lv[0], lv[1]]  # type: ignore[index]
        self._params = [_block_params(b) for b in blocks]
        final = cast(Conv1dBlock, net.final[0]).block
        self._final = (
            cast(nn.Conv1d, final[0]),
            cast(nn.GroupNorm, final[1]),
            cast(nn.Conv1d, net.final[1]),
        )
        self._widths = [2 * b.c_out for b in blocks]
        te = cfg.time_embed_dim
        with torch.inference_mode():
            w = torch.cat([p[8] for p in self._params], 0)  # (sum 2c, te + obs_cond)
            b = torch.cat([p[9] for p in self._params], 0)
            self._film_w_obs = w[:, te:].t().contiguous()
            times = torch.tensor(self.schedule.times, dtype=torch.float32)
            temb = net.time_mlp(sinusoidal_embedding(times, te))
            # Time part of every block's FiLM for every step: (S, sum 2c), bias included.
            # FiLM's Linear sees mish([temb, obs_cond]), which splits column-wise.
            self._film_time = torch.addmm(b, mish(temb), w[:, :te].t())

    def film(self, obs_cond: Tensor) -> list[list[tuple[Tensor, Tensor]]]:
        """Per step, per block: (scale, bias), each (B, 1, C, 1) for the B encoded
        conditions ``obs_cond`` (B, C)."""
        obs_part = mish(obs_cond) @ self._film_w_obs  # (B, sum 2c)
        full = self._film_time[:, None, :] + obs_part[None]  # (S, B, sum 2c)
        out = []
        for s in range(full.shape[0]):
            per_block = []
            for chunk in torch.split(full[s], self._widths, dim=-1):
                scale, bias = chunk[:, None, :, None].chunk(2, dim=2)
                per_block.append((scale, bias))
            out.append(per_block)
        return out

    def _block(self, i: int, x: Tensor, film: tuple[Tensor, Tensor], b: int) -> Tensor:
        w1, b1, g1w, g1b, w2, b2, g2w, g2b, _, _, rw, rb = self._params[i]
        h = mish(F.group_norm(F.conv1d(x, w1, b1, padding=self.pad), self.groups, g1w, g1b))
        n, c, t = h.shape
        scale, bias = film
        h = torch.addcmul(bias, scale, h.view(b, n // b, c, t)).view(n, c, t)
        h = mish(F.group_norm(F.conv1d(h, w2, b2, padding=self.pad), self.groups, g2w, g2b))
        return h.add_(x if rw is None else F.conv1d(x, rw, rb))

    def denoise(self, x: Tensor, film: list[tuple[Tensor, Tensor]], b: int) -> Tensor:
        """Network output for chunks ``x`` (B * K, H, A), rows grouped by window, given one
        step's FiLM tables from :meth:`film` for the B windows."""
        net = self.net
        h = x.transpose(1, 2)
        skips: list[Tensor] = []
        i = 0
        for lv in net.down:
            h = self._block(i, h, film[i], b)
            h = self._block(i + 1, h, film[i + 1], b)
            i += 2
            skips.append(h)
            down = lv[2]  # type: ignore[index]
            if isinstance(down, nn.Conv1d):
                h = F.conv1d(h, down.weight, down.bias, stride=2, padding=1)
        for _ in net.mid:
            h = self._block(i, h, film[i], b)
            i += 1
        for lv in net.up:
            h = torch.cat([h, skips.pop()], dim=1)
            h = self._block(i, h, film[i], b)
            h = self._block(i + 1, h, film[i + 1], b)
            i += 2
            up = lv[2]  # type: ignore[index]
            h = F.conv_transpose1d(h, up.weight, up.bias, stride=2, padding=1)
        conv, gn, head = self._final
        h = mish(F.group_norm(F.conv1d(h, conv.weight, conv.bias, padding=self.pad),
                              self.groups, gn.weight, gn.bias))  # fmt: skip
        out = F.conv1d(h, head.weight, head.bias)
        return out.transpose(1, 2)

    def sample_from_condition(self, obs_cond: Tensor, noise: Tensor) -> Tensor:
        """Chunks (B * K, H, A) from ``noise`` (B * K, H, A) given the encoded conditions
        ``obs_cond`` (B, C) of B windows (K = rows of noise per window)."""
        b = obs_cond.shape[0]
        if noise.shape[0] % b:
            raise ValueError(f"{noise.shape[0]} noise rows do not split over {b} windows")
        with torch.inference_mode():
            tables = self.film(obs_cond)
            x = noise
            sch = self.schedule
            for s in range(sch.steps):
                out = self.denoise(x, tables[s], b)
                x = out.mul_(sch.gain[s]) if sch.keep[s] == 0.0 else out.mul_(
                    sch.gain[s]).add_(x, alpha=sch.keep[s])  # fmt: skip
            return x

    def sample(
        self,
        hist: Tensor,
        hist_mask: Tensor,
        goal: Tensor,
        k: int = 1,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """``k`` standardised chunks per window: (B * k, H, A), rows grouped by window; the
        noise is drawn as :meth:`rmi_learn.planning.planner.Planner.sample` draws it."""
        cfg = self.net.config
        with torch.inference_mode():
            obs_cond = self.net.encode_condition(hist, hist_mask, goal)
            shape = (hist.shape[0] * k, cfg.horizon, cfg.action_dim)
            noise = torch.randn(shape, generator=generator).to(hist.device)
            return self.sample_from_condition(obs_cond, noise)


__all__ = ["FastSampler", "Objective", "Schedule", "mish", "schedule"]
