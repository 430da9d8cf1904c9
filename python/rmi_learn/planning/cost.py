"""The paper's combined cost of an action chunk (Sec. IV.C, Eq. rank)::

    J = 1 * J_M + 1e-4 * J_F + 0.05 * J_S + 0.1 * J_U

with (our concrete definitions; the paper names the terms only):

- ``J_M`` (g): ``|M_hat^L_{t+H_pi} - g_t|``, the world model's terminal retained water after the
  last command of the chunk against the goal, in grams.
- ``J_F`` (N): peak commanded force ``max_tau F_target``.
- ``J_S`` (-): predicted slip probability, the mean over the horizon of
  ``P(slip) + P(mixed)`` from the friction head (mixed contact contains slipping particles).
- ``J_U``: action jerk, the mean over the chunk of the absolute second difference of the
  force setpoint in N per step^2.

An ensemble of scorers adds ``J_D``, the spread of its members' water forecasts.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from rmi_learn.data.schema import CONTROL_ACTIONS, FORCE_LIMIT_N, FRICTION_CLASSES

#: Index of F_target in the action vector.
FORCE = CONTROL_ACTIONS.index("F_target")
#: Friction classes counted as slipping (indices into FRICTION_CLASSES: none/stick/slip/mixed).
SLIP_CLASSES = (FRICTION_CLASSES.index("slip"), FRICTION_CLASSES.index("mixed"))


@dataclass(frozen=True)
class CostWeights:
    """Weights of the combined cost (paper values). ``disagreement`` weighs ``J_D``, the
    spread of an ensemble's water forecasts (zero for a single scorer)."""

    water: float = 1.0
    force: float = 1e-4
    slip: float = 0.05
    jerk: float = 0.1
    disagreement: float = 1.0


def clip_forces(u_phys: Tensor, limit: float = FORCE_LIMIT_N) -> Tensor:
    """Clamp the force setpoints to [0, limit] N."""
    return u_phys.clamp(0.0, limit)


def jerk(u_phys: Tensor) -> Tensor:
    """Mean |second difference| of the force setpoints (N/step^2): (...,)."""
    d2 = u_phys[..., 2:, :] - 2.0 * u_phys[..., 1:-1, :] + u_phys[..., :-2, :]
    return d2[..., FORCE].abs().mean(-1)


def cost_terms(
    water_terminal_kg: Tensor,
    goal_kg: Tensor,
    u_phys: Tensor,
    p_fric: Tensor,
    weights: CostWeights | None = None,
    water_spread_kg: Tensor | None = None,
) -> dict[str, Tensor]:
    """Cost terms and J for a batch of chunks.

    ``water_terminal_kg`` (...,) predicted M_L after the last command; ``goal_kg`` (...,);
    ``u_phys`` (..., H, 1) force setpoints in N; ``p_fric`` (..., H, 4) friction probabilities;
    ``water_spread_kg`` (...,) the standard deviation of an ensemble's terminal M_L forecasts
    (None: a single scorer). Returns ``J_M`` (g), ``J_D`` (g), ``J_F`` (N), ``J_S`` (-),
    ``J_U`` and ``J``, each (...,).
    """
    w = weights or CostWeights()
    j_m = 1000.0 * (water_terminal_kg - goal_kg).abs()
    j_d = torch.zeros_like(j_m) if water_spread_kg is None else 1000.0 * water_spread_kg
    j_f = u_phys[..., FORCE].amax(-1)
    j_s = p_fric[..., list(SLIP_CLASSES)].sum(-1).mean(-1)
    j_u = jerk(u_phys)
    j = w.water * j_m + w.disagreement * j_d + w.force * j_f + w.slip * j_s + w.jerk * j_u
    return {"J_M": j_m, "J_D": j_d, "J_F": j_f, "J_S": j_s, "J_U": j_u, "J": j}


__all__ = ["FORCE", "SLIP_CLASSES", "CostWeights", "clip_forces", "cost_terms", "jerk"]
