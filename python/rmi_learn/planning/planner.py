"""The planner: K policy samples per window, converted to physical units, force-limited to
[0, FORCE_LIMIT_N] (the gripper's limit in N), scored by a world model and the chunk with the
smallest combined cost (:mod:`rmi_learn.planning.cost`) selected. The original (collected)
chunk can be scored alongside; it is never clipped. All chunks are returned in physical
units (N) so closed-loop execution can reuse them."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.planning.cost import CostWeights, clip_forces
from rmi_learn.planning.scorers import Scorer, score_chunks
from rmi_learn.planning.standardiser import Standardiser
from rmi_learn.policies.diffusion import DiffusionObjective
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.unet import PolicyUNet


@dataclass
class PlanResult:
    """Output of :meth:`Planner.plan` for B windows and K samples (physical units).

    ``samples`` (B, K, H, 1) clipped policy chunks; ``first`` = ``samples[:, 0]``;
    ``selected`` = ``samples[b, index[b]]``; ``original`` (B, H, 1) collected chunk or None;
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
        """First policy sample per window (B, H, 1), N."""
        return self.samples[:, 0]

    @property
    def selected(self) -> Tensor:
        """Selected (argmin J) sample per window (B, H, 1), N."""
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

    ``objective`` is a :class:`~rmi_learn.policies.diffusion.DiffusionObjective` or
    :class:`~rmi_learn.policies.flow.FlowObjective`; ``scorer`` follows :data:`Scorer`.
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
        """K clipped physical chunks per window: (B, K, H, 1), one batched sampling pass."""
        b = hist.shape[0]
        cfg = self.policy.config
        obs_cond = self.policy.encode_condition(hist, hist_mask, goal)
        obs_cond = obs_cond.repeat_interleave(self.k, dim=0)
        noise = torch.randn((b * self.k, cfg.horizon, cfg.action_dim), generator=generator)
        chunks = self.objective.sample_from_condition(self.policy, obs_cond, noise.to(hist.device))
        phys = clip_forces(self.std.u_to_phys(chunks), self.force_limit)
        out: Tensor = phys.view(b, self.k, cfg.horizon, cfg.action_dim)
        return out

    def score(
        self,
        hist: Tensor,
        hist_mask: Tensor,
        u_phys: Tensor,
        goal_kg: Tensor,
        step: int | None = None,
    ) -> tuple[dict[str, Tensor], Tensor]:
        """Costs of physical chunks ``u_phys`` (B, M, H, 1) for B windows: ((B, M) each, M_L kg);
        see :func:`score_chunks`."""
        return score_chunks(
            self.scorer, self.std, hist, hist_mask, u_phys, goal_kg, self.weights, step
        )

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
        ``original_std`` (B, H, 1) standardised collected chunk to score alongside (optional).
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


__all__ = ["PlanResult", "Planner"]
