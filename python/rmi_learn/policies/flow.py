"""Rectified-flow (flow-matching) objective on the shared :class:`PolicyUNet`.

Convention (pinned by ``tests/policies/test_policy.py``; pi0/openpi use the opposite direction):
``t = 0`` is noise and ``t = 1`` is data, ``x_t = (1 - t) eps + t A``, the network regresses
the constant velocity ``A - eps``, and sampling integrates ``dx/dt = v(x, t)`` with 20
explicit Euler steps from ``t = 0`` to ``t = 1``. The network receives ``t * 1000`` so that
the sinusoidal embedding, built for integer diffusion steps, resolves the unit interval.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from rmi_learn.policies.unet import ChunkSampler, PolicyUNet

#: Multiplier from flow time in [0, 1] to the step units of the sinusoidal embedding.
TIME_SCALE = 1000.0


def interpolate(actions: Tensor, eps: Tensor, t: Tensor) -> Tensor:
    """``x_t = (1 - t) eps + t A`` for per-sample times ``t`` (N,) in [0, 1]."""
    tt = t.view(-1, *([1] * (actions.dim() - 1)))
    return (1.0 - tt) * eps + tt * actions


def euler_integrate(
    velocity: Callable[[Tensor, Tensor], Tensor], x0: Tensor, n_steps: int = 20
) -> Tensor:
    """Integrate ``dx/dt = velocity(x, t)`` from t = 0 (noise) to t = 1 (data).

    ``velocity`` receives ``x`` and the per-sample flow time ``t`` (N,) in [0, 1).
    """
    x = x0
    dt = 1.0 / n_steps
    for i in range(n_steps):
        t = torch.full((x.shape[0],), i * dt, device=x.device)
        x = x + dt * velocity(x, t)
    return x


class FlowObjective(ChunkSampler):
    """Rectified flow: target ``A - eps``, 20 Euler steps, ``t * 1000`` time embedding."""

    name = "flow"

    def __init__(self, n_sample_steps: int = 20, time_scale: float = TIME_SCALE) -> None:
        self.n_sample_steps = n_sample_steps
        self.time_scale = time_scale

    def config(self) -> dict[str, object]:
        """JSON-friendly description (saved next to the checkpoint)."""
        return {
            "objective": self.name,
            "n_sample_steps": self.n_sample_steps,
            "time_scale": self.time_scale,
        }

    def loss(
        self,
        model: PolicyUNet,
        actions: Tensor,
        hist: Tensor,
        hist_mask: Tensor,
        goal: Tensor,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """Flow MSE ``|v(x_t, t) - (A - eps)|^2`` averaged over all elements, t ~ U(0, 1).

        Returns the scalar loss and ``{"t": times (N,), "mse": per-sample MSE}``.
        """
        n = actions.shape[0]
        t = torch.rand((n,), generator=generator).to(actions.device)
        eps = torch.randn(actions.shape, generator=generator).to(actions.device)
        x_t = interpolate(actions, eps, t)
        pred = model(x_t, t * self.time_scale, hist, hist_mask, goal)
        mse = (pred - (actions - eps)).pow(2).flatten(1).mean(1)
        return mse.mean(), {"t": t.detach(), "mse": mse.detach()}

    @torch.no_grad()
    def sample_from_condition(self, model: PolicyUNet, obs_cond: Tensor, noise: Tensor) -> Tensor:
        """Euler-integrate the learned velocity from ``noise`` (N, H, 1) to a chunk."""

        def velocity(x: Tensor, t: Tensor) -> Tensor:
            return model.denoise(x, t * self.time_scale, obs_cond)

        return euler_integrate(velocity, noise, self.n_sample_steps)
