"""Scorers: world models that forecast the outcome of action chunks, as the planner calls
them, and the costs of chunks under a scorer."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from rmi_learn.planning.cost import CostWeights, cost_terms
from rmi_learn.planning.standardiser import WATER, Standardiser

#: ``scorer(hist, hist_mask, actions_std) -> (z_std (N,H,18), p_contact (N,H), p_fric (N,H,4))``
Scorer = Callable[[Tensor, Tensor, Tensor], tuple[Tensor, Tensor, Tensor]]


def can_score(model: Any, horizon: int) -> str | None:
    """Why the world model ``model`` cannot rank chunks of ``horizon`` steps, or None."""
    if model.kind == "baseline" or not getattr(model, "action_conditioned", True):
        return "does not see the actions"
    if getattr(model, "observation_mode", "privileged") != "privileged":
        return "reads the sensors (the chunks are scored from y_t histories)"
    try:
        model.check_horizon_length(horizon)
    except ValueError as exc:
        return str(exc)
    return None


@torch.no_grad()
def score_chunks(
    scorer: Scorer,
    std: Standardiser,
    hist: Tensor,
    hist_mask: Tensor,
    u_phys: Tensor,
    goal_kg: Tensor,
    weights: CostWeights | None = None,
    step: int | None = None,
) -> tuple[dict[str, Tensor], Tensor]:
    """Costs of physical chunks ``u_phys`` (B, M, H, 1) for B windows (``hist``/``hist_mask``
    (B, L, 23)) against goals ``goal_kg`` (B,): ((B, M) each, predicted M_L in kg).

    The water term compares the forecast after command ``step`` (0-based; default the last,
    H - 1) with the goal. One batched scorer call over B * M rollouts; an
    :class:`EnsembleScorer` adds the spread of its members' forecasts as ``J_D``.
    """
    b, m, h, _ = u_phys.shape
    at = h - 1 if step is None else step
    if not getattr(scorer, "shares_history", False):
        hist = hist.repeat_interleave(m, dim=0)
        hist_mask = hist_mask.repeat_interleave(m, dim=0)
    actions = std.u_to_std(u_phys.reshape(b * m, h, -1))
    spread = None
    if isinstance(scorer, EnsembleScorer):
        members, p_f = scorer.members_water(hist, hist_mask, actions, at)
        kg = std.water_to_kg(members).view(b, m, -1)
        water, spread = kg.mean(-1), kg.std(-1, unbiased=False)
    else:
        z, _p_c, p_f = scorer(hist, hist_mask, actions)
        water = std.water_to_kg(z[:, at, WATER]).view(b, m)
    costs = cost_terms(
        water, goal_kg[:, None].expand(b, m), u_phys, p_f.view(b, m, h, -1), weights, spread
    )
    return costs, water


def world_model_scorer(model: torch.nn.Module) -> Scorer:
    """Adapt a :class:`rmi_learn.world_models.WorldModel` (e.g. the Transformer W_T) to
    :data:`Scorer`: free rollout in eval mode, standardised z, contact and friction
    probabilities; differentiable in the actions where the caller enables gradients. The
    scorer carries the model's ``shares_history`` flag: when set, it takes B histories with
    B * M chunks and encodes each history once."""

    def score(hist: Tensor, hist_mask: Tensor, actions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        out = model.forecast(hist, hist_mask, actions)  # type: ignore[operator]
        return out["z"], out["p_contact"], out["p_friction"]

    score.shares_history = bool(getattr(model, "shares_history", False))  # type: ignore[attr-defined]
    return score


class EnsembleScorer:
    """Several scorers as one: the mean of their forecasts, and in :meth:`Planner.score` the
    spread (standard deviation over members) of their terminal water forecasts as the
    disagreement cost ``J_D``, so that a chunk on which the models disagree ranks lower.

    Called as a :data:`Scorer`, it returns the members' mean forecast and probabilities.
    """

    shares_history = False

    def __init__(self, members: dict[str, Scorer]) -> None:
        if len(members) < 2:
            raise ValueError("an ensemble needs at least two scorers")
        self.members = dict(members)

    def _each(
        self, hist: Tensor, hist_mask: Tensor, actions: Tensor
    ) -> list[tuple[Tensor, Tensor, Tensor]]:
        n_hist, n = hist.shape[0], actions.shape[0]
        outs = []
        for scorer in self.members.values():
            if getattr(scorer, "shares_history", False) and n_hist != n:
                raise ValueError("EnsembleScorer takes one history per chunk")
            outs.append(scorer(hist, hist_mask, actions))
        return outs

    def __call__(
        self, hist: Tensor, hist_mask: Tensor, actions: Tensor
    ) -> tuple[Tensor, Tensor, Tensor]:
        outs = self._each(hist, hist_mask, actions)
        return tuple(torch.stack(x).mean(0) for x in zip(*outs, strict=True))  # type: ignore[return-value]

    def members_water(
        self, hist: Tensor, hist_mask: Tensor, actions: Tensor, step: int
    ) -> tuple[Tensor, Tensor]:
        """Each member's standardised M_L forecast after command ``step``, (N, members), and
        the members' mean friction probabilities (N, H, 4)."""
        outs = self._each(hist, hist_mask, actions)
        water = torch.stack([z[:, step, WATER] for z, _, _ in outs], dim=-1)
        return water, torch.stack([p for _, _, p in outs]).mean(0)


__all__ = ["EnsembleScorer", "Scorer", "can_score", "score_chunks", "world_model_scorer"]
