"""Diffusion Policy objective: cosine schedule, x0 prediction, min-SNR weights, DDIM sampling.

Conventions (pinned by ``tests/policies/test_policy.py``):

- 50 training steps ``t = 0..49`` with the cosine ("squaredcos_cap_v2") schedule;
  ``abar[t]`` is the cumulative product of ``1 - beta``; ``abar(-1) = 1`` (clean data).
- Forward process ``x_t = sqrt(abar_t) A + sqrt(1 - abar_t) eps``; the network predicts the
  clean chunk ``A`` (x0 / "sample" prediction).
- Min-SNR weight for x0 prediction: ``w_t = max(min(SNR_t, gamma), floor)`` with
  ``SNR_t = abar_t / (1 - abar_t)`` and ``gamma = 5`` (for epsilon prediction it would be
  ``min(SNR, gamma) / SNR``). ``floor`` defaults to 0 (the paper's weighting); at t = 49 the
  weight is about 1e-6, so the training loop also logs the unweighted loss per noise bucket.
- Sampling: deterministic DDIM (eta = 0) over explicit ``(t, t_prev)`` pairs that start at
  ``t = 49`` and end at ``t_prev = -1``; with 16 steps the network is evaluated 16 times.
- No clipping in standardised action space (clipping to [-1, 1] is only valid with min-max
  normalisation); physical limits (forces <= FORCE_LIMIT_N) are applied after destandardising.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from rmi_learn.policies.unet import ChunkSampler, PolicyUNet


def cosine_alpha_bar(n_steps: int = 50, max_beta: float = 0.999) -> Tensor:
    """Cumulative signal fraction ``abar[t]``, t = 0..n_steps-1, of the cosine schedule.

    ``beta_i = min(1 - f((i+1)/T) / f(i/T), max_beta)`` with
    ``f(s) = cos((s + 0.008) / 1.008 * pi / 2)^2`` and ``abar = cumprod(1 - beta)``
    (float64 for accuracy). Dimensionless.
    """

    def f(s: float) -> float:
        return math.cos((s + 0.008) / 1.008 * math.pi / 2) ** 2

    betas = [min(1.0 - f((i + 1) / n_steps) / f(i / n_steps), max_beta) for i in range(n_steps)]
    return torch.cumprod(1.0 - torch.tensor(betas, dtype=torch.float64), dim=0)


def min_snr_weight(
    alpha_bar: Tensor, gamma: float = 5.0, floor: float = 0.0, prediction: str = "sample"
) -> Tensor:
    """Min-SNR-gamma loss weight per step for the given prediction target.

    ``prediction="sample"`` (x0): ``min(SNR, gamma)``; ``"epsilon"``: ``min(SNR, gamma)/SNR``.
    The result is raised to at least ``floor``. Dimensionless.
    """
    snr = alpha_bar / (1.0 - alpha_bar)
    clipped = torch.clamp(snr, max=gamma)
    if prediction == "sample":
        w = clipped
    elif prediction == "epsilon":
        w = clipped / snr
    else:
        raise ValueError(f"unknown prediction type {prediction!r}")
    return torch.clamp(w, min=floor)


def ddim_step_pairs(n_train_steps: int = 50, n_sample_steps: int = 16) -> list[tuple[int, int]]:
    """Explicit DDIM ``(t, t_prev)`` pairs: start at ``T - 1``, end at ``(0, -1)``.

    The ``n_sample_steps`` visited steps are ``round(linspace(T - 1, 0, S))`` (strictly
    decreasing, first ``T - 1``, last 0); each is paired with the next one and the last with
    ``-1`` (``abar(-1) = 1``), so sampling evaluates the network exactly S times and the
    final update returns the predicted clean chunk.
    """
    if not 1 <= n_sample_steps <= n_train_steps:
        raise ValueError(f"need 1 <= sample steps <= {n_train_steps}, got {n_sample_steps}")
    if n_sample_steps == 1:
        steps = [n_train_steps - 1]
    else:
        span = n_train_steps - 1
        steps = [int(round(span - i * span / (n_sample_steps - 1))) for i in range(n_sample_steps)]
    if len(set(steps)) != len(steps):
        raise AssertionError(f"duplicate DDIM steps {steps}")
    return list(zip(steps, [*steps[1:], -1], strict=True))


class DiffusionObjective(ChunkSampler):
    """x0-prediction DDPM training and DDIM sampling for :class:`PolicyUNet`."""

    name = "diffusion"

    def __init__(
        self,
        n_train_steps: int = 50,
        n_sample_steps: int = 16,
        snr_gamma: float = 5.0,
        snr_floor: float = 0.0,
    ) -> None:
        self.n_train_steps = n_train_steps
        self.n_sample_steps = n_sample_steps
        self.snr_gamma = snr_gamma
        self.snr_floor = snr_floor
        self.alpha_bar = cosine_alpha_bar(n_train_steps)
        self.weights = min_snr_weight(self.alpha_bar, snr_gamma, snr_floor).float()
        self.pairs = ddim_step_pairs(n_train_steps, n_sample_steps)

    def config(self) -> dict[str, object]:
        """JSON-friendly description (saved next to the checkpoint)."""
        return {
            "objective": self.name,
            "n_train_steps": self.n_train_steps,
            "n_sample_steps": self.n_sample_steps,
            "snr_gamma": self.snr_gamma,
            "snr_floor": self.snr_floor,
        }

    def abar(self, t: Tensor) -> Tensor:
        """``abar`` at integer steps ``t`` (float32), with ``abar(-1) = 1``."""
        ab = torch.cat([torch.ones(1, dtype=torch.float64), self.alpha_bar])
        return ab.to(t.device)[t.long() + 1].float()

    def add_noise(self, actions: Tensor, eps: Tensor, t: Tensor) -> Tensor:
        """``x_t = sqrt(abar_t) A + sqrt(1 - abar_t) eps`` for per-sample steps ``t`` (N,)."""
        ab = self.abar(t).view(-1, *([1] * (actions.dim() - 1)))
        return ab.sqrt() * actions + (1.0 - ab).sqrt() * eps

    def loss(
        self,
        model: PolicyUNet,
        actions: Tensor,
        hist: Tensor,
        hist_mask: Tensor,
        goal: Tensor,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """Min-SNR weighted x0 MSE on a batch of standardised chunks ``actions`` (N, H, 1).

        Returns the scalar loss and ``{"t": steps (N,), "mse": unweighted per-sample MSE}``
        for per-noise-bucket logging.
        """
        n = actions.shape[0]
        t = torch.randint(0, self.n_train_steps, (n,), generator=generator).to(actions.device)
        eps = torch.randn(actions.shape, generator=generator).to(actions.device)
        x_t = self.add_noise(actions, eps, t)
        pred = model(x_t, t.float(), hist, hist_mask, goal)
        mse = (pred - actions).pow(2).flatten(1).mean(1)
        w = self.weights.to(actions.device)[t]
        return (w * mse).mean(), {"t": t.detach(), "mse": mse.detach()}

    @torch.no_grad()
    def sample_from_condition(self, model: PolicyUNet, obs_cond: Tensor, noise: Tensor) -> Tensor:
        """DDIM (eta = 0) from ``noise`` (N, H, 1) given the encoded condition (N, C)."""
        x = noise
        n = x.shape[0]
        for t, t_prev in self.pairs:
            ab_t = float(self.alpha_bar[t])
            ab_prev = 1.0 if t_prev < 0 else float(self.alpha_bar[t_prev])
            tt = torch.full((n,), float(t), device=x.device)
            x0 = model.denoise(x, tt, obs_cond)
            eps = (x - math.sqrt(ab_t) * x0) / math.sqrt(1.0 - ab_t)
            x = math.sqrt(ab_prev) * x0 + math.sqrt(1.0 - ab_prev) * eps
        return x
