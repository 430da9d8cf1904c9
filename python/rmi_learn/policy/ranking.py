"""World-model ranking of policy samples (paper Sec. IV.C, Eq. rank).

For every window, K = 8 chunks are drawn from the policy in one batch, converted to physical
units, force-limited to [0, 400] N, scored by the causal world model W_T, and the chunk with the
smallest combined cost is selected::

    J = 1 * J_M + 1e-4 * J_F + 0.05 * J_S + 0.1 * J_U

with (our concrete definitions; the paper names the terms only):

- ``J_M`` (g): ``|M_hat^L_{t+H_pi} - g_t|``, the world model's terminal retained water after the
  last command of the chunk against the goal, in grams.
- ``J_F`` (N): peak commanded force ``max_tau F_target``.
- ``J_S`` (-): predicted slip probability, the mean over the horizon of
  ``P(slip) + P(mixed)`` from the friction head (mixed contact contains slipping particles).
- ``J_U``: action jerk, the mean over the chunk of the absolute second difference of the
  force command in N per step^2 plus that of the velocity command in mm/s per step^2.

The same cost is computed for the original (collected) chunk, which is never clipped. All
chunks are returned in physical units (N, m/s) so closed-loop execution can reuse them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from rmi_learn.policy.diffusion import DiffusionObjective
from rmi_learn.policy.flow import FlowObjective
from rmi_learn.policy.unet import PolicyUNet
from rmi_learn.schema import FRICTION_CLASSES

#: Force limit applied to every policy sample (N).
FORCE_LIMIT_N = 400.0
#: Index of F_target and v_cmd in the action vector, and of M_L in the continuous state.
FORCE, VEL, WATER = 0, 1, 0
#: Friction classes counted as slipping (indices into FRICTION_CLASSES: none/stick/slip/mixed).
SLIP_CLASSES = (FRICTION_CLASSES.index("slip"), FRICTION_CLASSES.index("mixed"))

#: ``scorer(hist, hist_mask, actions_std) -> (z_std (N,H,18), p_contact (N,H), p_fric (N,H,4))``
Scorer = Callable[[Tensor, Tensor, Tensor], tuple[Tensor, Tensor, Tensor]]


@dataclass(frozen=True)
class CostWeights:
    """Weights of the combined cost (paper values)."""

    water: float = 1.0
    force: float = 1e-4
    slip: float = 0.05
    jerk: float = 0.1


@dataclass(frozen=True)
class Standardiser:
    """Training-split mean/std of the 18 continuous channels and the 2 actions (SI units)."""

    z_mean: Tensor
    z_std: Tensor
    u_mean: Tensor
    u_std: Tensor

    @classmethod
    def from_stats(cls, stats: object) -> Standardiser:
        """From a ``Dataset.stats``-like object with ``z_mean, z_std, u_mean, u_std``."""

        def t(name: str) -> Tensor:
            return torch.as_tensor(np.asarray(getattr(stats, name)), dtype=torch.float32)

        return cls(t("z_mean"), t("z_std"), t("u_mean"), t("u_std"))

    def u_to_phys(self, u: Tensor) -> Tensor:
        """Standardised actions (..., 2) -> (N, m/s)."""
        return u * self.u_std + self.u_mean

    def u_to_std(self, u: Tensor) -> Tensor:
        """Physical actions (..., 2) in (N, m/s) -> standardised."""
        return (u - self.u_mean) / self.u_std

    def water_to_kg(self, w: Tensor) -> Tensor:
        """Standardised M_L -> kg."""
        return w * self.z_std[WATER] + self.z_mean[WATER]

    def goal_vector(self, goal_std: Tensor, water_now_std: Tensor) -> Tensor:
        """Policy goal ``[g, Delta M]`` (N, 2) from standardised g and M_L(t).

        ``g`` keeps the dataset's standardisation of M_L; ``Delta M = g - M_L(t)`` is divided
        by the same std without a mean shift (it is a difference), i.e. both are in units of
        the training-split M_L standard deviation.
        """
        return torch.stack([goal_std, goal_std - water_now_std], dim=-1)


def clip_forces(u_phys: Tensor, limit: float = FORCE_LIMIT_N) -> Tensor:
    """Clamp the force command to [0, limit] N; velocity unchanged."""
    f = u_phys[..., FORCE].clamp(0.0, limit)
    return torch.stack([f, u_phys[..., VEL]], dim=-1)


def jerk(u_phys: Tensor) -> Tensor:
    """Mean |second difference| of force (N/step^2) plus velocity (mm/s/step^2): (...,)."""
    d2 = u_phys[..., 2:, :] - 2.0 * u_phys[..., 1:-1, :] + u_phys[..., :-2, :]
    return d2[..., FORCE].abs().mean(-1) + 1000.0 * d2[..., VEL].abs().mean(-1)


def cost_terms(
    water_terminal_kg: Tensor,
    goal_kg: Tensor,
    u_phys: Tensor,
    p_fric: Tensor,
    weights: CostWeights | None = None,
) -> dict[str, Tensor]:
    """Cost terms and J for a batch of chunks.

    ``water_terminal_kg`` (...,) predicted M_L after the last command; ``goal_kg`` (...,);
    ``u_phys`` (..., H, 2) in N and m/s; ``p_fric`` (..., H, 4) friction probabilities.
    Returns ``J_M`` (g), ``J_F`` (N), ``J_S`` (-), ``J_U`` and ``J``, each (...,).
    """
    w = weights or CostWeights()
    j_m = 1000.0 * (water_terminal_kg - goal_kg).abs()
    j_f = u_phys[..., FORCE].amax(-1)
    j_s = p_fric[..., list(SLIP_CLASSES)].sum(-1).mean(-1)
    j_u = jerk(u_phys)
    j = w.water * j_m + w.force * j_f + w.slip * j_s + w.jerk * j_u
    return {"J_M": j_m, "J_F": j_f, "J_S": j_s, "J_U": j_u, "J": j}


@dataclass
class PlanResult:
    """Output of :meth:`Planner.plan` for B windows and K samples (physical units).

    ``samples`` (B, K, H, 2) clipped policy chunks; ``first`` = ``samples[:, 0]``;
    ``selected`` = ``samples[b, index[b]]``; ``original`` (B, H, 2) collected chunk or None;
    ``costs[name]`` (B, K) per sample; ``original_costs[name]`` (B,) or empty;
    ``pred_water_kg`` (B, K) predicted terminal M_L; ``goal_kg`` (B,).
    """

    samples: Tensor
    index: Tensor
    costs: dict[str, Tensor]
    goal_kg: Tensor
    pred_water_kg: Tensor
    original: Tensor | None = None
    original_costs: dict[str, Tensor] = field(default_factory=dict)

    @property
    def first(self) -> Tensor:
        """First policy sample per window (B, H, 2), N and m/s."""
        return self.samples[:, 0]

    @property
    def selected(self) -> Tensor:
        """Selected (argmin J) sample per window (B, H, 2), N and m/s."""
        b = torch.arange(self.samples.shape[0])
        return self.samples[b, self.index]

    def selected_costs(self) -> dict[str, Tensor]:
        """Cost terms of the selected sample (B,)."""
        b = torch.arange(self.samples.shape[0])
        return {k: v[b, self.index] for k, v in self.costs.items()}

    def first_costs(self) -> dict[str, Tensor]:
        """Cost terms of the first sample (B,)."""
        return {k: v[:, 0] for k, v in self.costs.items()}


class Planner:
    """K-sample policy proposals ranked by a world-model scorer.

    ``objective`` is a :class:`~rmi_learn.policy.diffusion.DiffusionObjective` or
    :class:`~rmi_learn.policy.flow.FlowObjective`; ``scorer`` follows :data:`Scorer`.
    """

    def __init__(
        self,
        policy: PolicyUNet,
        objective: DiffusionObjective | FlowObjective,
        scorer: Scorer,
        standardiser: Standardiser,
        k: int = 8,
        weights: CostWeights | None = None,
        force_limit: float = FORCE_LIMIT_N,
    ) -> None:
        self.policy = policy.eval()
        self.objective = objective
        self.scorer = scorer
        self.std = standardiser
        self.k = k
        self.weights = weights or CostWeights()
        self.force_limit = force_limit

    @torch.no_grad()
    def sample(
        self,
        hist: Tensor,
        hist_mask: Tensor,
        goal: Tensor,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """K clipped physical chunks per window: (B, K, H, 2), one batched sampling pass."""
        b = hist.shape[0]
        cfg = self.policy.config
        obs_cond = self.policy.encode_condition(hist, hist_mask, goal)
        obs_cond = obs_cond.repeat_interleave(self.k, dim=0)
        noise = torch.randn((b * self.k, cfg.horizon, cfg.action_dim), generator=generator)
        chunks = self.objective.sample_from_condition(self.policy, obs_cond, noise.to(hist.device))
        phys = clip_forces(self.std.u_to_phys(chunks), self.force_limit)
        out: Tensor = phys.view(b, self.k, cfg.horizon, cfg.action_dim)
        return out

    @torch.no_grad()
    def score(
        self, hist: Tensor, hist_mask: Tensor, u_phys: Tensor, goal_kg: Tensor
    ) -> tuple[dict[str, Tensor], Tensor]:
        """Costs of physical chunks ``u_phys`` (B, M, H, 2) for B windows: ((B, M) each, M_L kg).

        One batched world-model call over B * M rollouts.
        """
        b, m, h, _ = u_phys.shape
        if not getattr(self.scorer, "shares_history", False):
            hist = hist.repeat_interleave(m, dim=0)
            hist_mask = hist_mask.repeat_interleave(m, dim=0)
        z, _p_c, p_f = self.scorer(hist, hist_mask, self.std.u_to_std(u_phys.reshape(b * m, h, 2)))
        water = self.std.water_to_kg(z[:, h - 1, WATER]).view(b, m)
        costs = cost_terms(
            water, goal_kg[:, None].expand(b, m), u_phys, p_f.view(b, m, h, -1), self.weights
        )
        return costs, water

    @torch.no_grad()
    def plan(
        self,
        hist: Tensor,
        hist_mask: Tensor,
        goal_std: Tensor,
        water_now_std: Tensor,
        original_std: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> PlanResult:
        """Sample K chunks per window, score them (and the original chunk) and select.

        ``hist``/``hist_mask`` (B, L, 23) as in the dataset windows; ``goal_std`` (B,) the
        standardised goal g (terminal M_L); ``water_now_std`` (B,) standardised M_L(t);
        ``original_std`` (B, H, 2) standardised collected chunk to score alongside (optional).
        """
        goal = self.std.goal_vector(goal_std, water_now_std)
        samples = self.sample(hist, hist_mask, goal, generator)
        goal_kg = self.std.water_to_kg(goal_std)
        original = None
        if original_std is not None:
            original = self.std.u_to_phys(original_std)
            cand = torch.cat([samples, original[:, None]], dim=1)
        else:
            cand = samples
        costs, water = self.score(hist, hist_mask, cand, goal_kg)
        k = self.k
        sample_costs = {name: v[:, :k] for name, v in costs.items()}
        orig_costs = {name: v[:, k] for name, v in costs.items()} if original is not None else {}
        index = sample_costs["J"].argmin(dim=1)
        return PlanResult(
            samples=samples,
            index=index,
            costs=sample_costs,
            goal_kg=goal_kg,
            pred_water_kg=water[:, :k],
            original=original,
            original_costs=orig_costs,
        )


def world_model_scorer(model: torch.nn.Module) -> Scorer:
    """Adapt a :class:`rmi_learn.models.WorldModel` (e.g. the Transformer W_T) to
    :data:`Scorer`: free rollout in eval mode, standardised z, contact and friction
    probabilities. The scorer carries the model's ``shares_history`` flag: when set, it takes
    B histories with B * M chunks and encodes each history once."""

    def score(hist: Tensor, hist_mask: Tensor, actions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        out = model.predict(hist, hist_mask, actions)  # type: ignore[operator]
        return out["z"], out["p_contact"], out["p_friction"]

    score.shares_history = bool(getattr(model, "shares_history", False))  # type: ignore[attr-defined]
    return score
