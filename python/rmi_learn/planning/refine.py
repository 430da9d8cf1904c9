"""Model-based refinement of a force chunk toward a water goal.

A policy proposes chunks and a world model ranks them, but ranking can only pick among the
proposals: when none ends near the goal, the best pick is still far from it. Refinement moves
the picked chunk itself. With the scorer's forecast ``p(u)`` of the retained water after
command ``step`` and its gradient ``J = dp/du`` (kg/N per setpoint, by automatic
differentiation through the world model), each iteration takes the smallest change of the
setpoints that closes the forecast gap under the linearisation (a Gauss-Newton step on
``(p(u) - g)^2``), smallest in a metric ``M``:

    u <- clip(u + (g - p(u)) M^-1 J / (J . M^-1 J), lower, upper)

- ``smooth`` (the default): ``M = D^T D`` with ``D`` the first difference of the change,
  starting from zero before the first setpoint: the change that varies least from step to
  step, so the force loop can track it (a gap that the model attributes to the last
  setpoints becomes a ramp toward them, not a jump).
- ``l2``: ``M = I``, the change of least Euclidean norm, concentrated where ``|J|`` is largest.

Setpoints held at a bound that the step pushes further out are frozen for that step, so the
rest of the chunk takes up the correction. For the Linear-ARX scorer ``p`` is affine in ``u``
and one step lands on the goal unless a bound is hit; for the recurrent and attention models a
few steps converge on their own forecast. How far the executed outcome follows the forecast is
what the goal-reaching benchmark measures.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from rmi_learn.data.schema import FORCE_LIMIT_N

#: Gauss-Newton iterations of :func:`refine_chunk`.
ITERATIONS = 4
#: Metrics of the change (see the module's documentation).
METRICS: tuple[str, ...] = ("smooth", "l2")
#: Added to J . J (kg^2/N^2) so that a scorer blind to the chunk leaves it unchanged.
_EPS = 1e-14


@dataclass
class Refined:
    """Result of :func:`refine_chunk` for N chunks: ``u`` (N, H, 1) refined setpoints (N),
    ``pred_before_kg`` / ``pred_after_kg`` (N,) the scorer's forecast of M_L after command
    ``step`` for the given and the refined chunk, ``change_N`` (N,) the largest setpoint
    change."""

    u: Tensor
    pred_before_kg: Tensor
    pred_after_kg: Tensor
    change_N: Tensor


def _forecast(scorer, std, hist: Tensor, hist_mask: Tensor, u: Tensor, step: int) -> Tensor:
    z, _p_c, _p_f = scorer(hist, hist_mask, std.u_to_std(u))
    return std.water_to_kg(z[:, step, 0])


def _metric(h: int, metric: str) -> Tensor | None:
    """The metric matrix M (H, H) in float64; None for ``l2`` (M = I)."""
    if metric == "l2":
        return None
    diff = torch.eye(h, dtype=torch.float64) - torch.diag(
        torch.ones(h - 1, dtype=torch.float64), -1
    )
    return diff.T @ diff


def _direction(j: Tensor, free: Tensor, m: Tensor | None) -> Tensor:
    """``M^-1 J`` over the free setpoints (zero on the frozen ones): (N, H, 1)."""
    if m is None:
        return j
    f = free[..., 0].to(j.dtype)  # (N, H)
    # Frozen setpoints: identity rows and columns, so the system stays regular and their
    # component of the solution is zero.
    mf = m * f[:, :, None] * f[:, None, :] + torch.diag_embed(1.0 - f)
    return torch.linalg.solve(mf, j[..., 0])[..., None]


def refine_chunk(
    scorer,
    std,
    hist: Tensor,
    hist_mask: Tensor,
    u_phys: Tensor,
    goal_kg: Tensor,
    step: int | None = None,
    *,
    lower: Tensor | float = 0.0,
    upper: float = FORCE_LIMIT_N,
    iterations: int = ITERATIONS,
    metric: str = "smooth",
) -> Refined:
    """Refine the force chunks ``u_phys`` (N, H, 1) in N so that ``scorer``'s forecast of the
    retained water after command ``step`` (0-based, default H - 1) meets ``goal_kg`` (N,) kg.

    ``scorer`` follows :data:`rmi_learn.planning.scorers.Scorer` and must be differentiable
    in the actions; ``std`` is the :class:`~rmi_learn.planning.standardiser.Standardiser`;
    ``hist``/``hist_mask`` (N, L, 23) one history per chunk. ``lower`` (N) is a bound, or a
    tensor broadcastable to ``u_phys``; ``upper`` the force limit (N); ``metric`` one of
    :data:`METRICS`. Returns :class:`Refined`; the scorer's parameters get no gradient."""
    if iterations < 0:
        raise ValueError(f"iterations must be >= 0, got {iterations}")
    if metric not in METRICS:
        raise ValueError(f"metric must be one of {METRICS}, got {metric!r}")
    n, h, _ = u_phys.shape
    at = h - 1 if step is None else int(step)
    if not 0 <= at < h:
        raise ValueError(f"step must lie in [0, {h - 1}], got {step}")
    lo = torch.as_tensor(lower, dtype=u_phys.dtype).expand_as(u_phys)
    u0 = u_phys.detach().clamp(max=upper)
    u = torch.maximum(u0, lo)
    goal = goal_kg.to(u.dtype).reshape(n)
    with torch.no_grad():
        before = _forecast(scorer, std, hist, hist_mask, u0, at)
    m = _metric(h, metric)
    for _ in range(iterations):
        with torch.enable_grad():
            x = u.clone().requires_grad_(True)
            p = _forecast(scorer, std, hist, hist_mask, x, at)
            (grad,) = torch.autograd.grad(p.sum(), x)
        gap = (goal - p.detach())[:, None, None]
        outward = grad * gap  # the sign of each setpoint's move
        free = ~(((x.detach() <= lo) & (outward < 0)) | ((x.detach() >= upper) & (outward > 0)))
        j = (grad * free).double()
        d = _direction(j, free, m)
        jd = (j * d).sum(dim=(1, 2), keepdim=True)
        step_u = (gap.double() * d / (jd + _EPS)).to(u.dtype)
        u = torch.minimum(torch.maximum(u + step_u, lo), torch.full_like(u, upper))
    with torch.no_grad():
        after = _forecast(scorer, std, hist, hist_mask, u, at)
    change = (u - u0).abs().amax(dim=(1, 2))
    return Refined(u.detach(), before, after, change)


__all__ = ["ITERATIONS", "Refined", "refine_chunk"]
