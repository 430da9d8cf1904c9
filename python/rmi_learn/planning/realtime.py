"""Real-time decision path: K policy samples and their world-model scores within one 20 ms
control period on a CPU.

:class:`RealtimePlanner` is the reference :class:`~rmi_learn.planning.planner.Planner` on the
fast sampling path (:mod:`rmi_learn.policies.fast_sampler`): the same K samples to float32
rounding for the same noise, the same cost and selection. It wraps the sampler, a scorer (the
native AC-GRU-WM rollout by default in :func:`load_realtime_planner`, W_T on request) and the
paper's cost into an ``act(hist, hist_mask, goal_kg) -> chunk`` call for a receding-horizon
controller.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from rmi_learn import world_models as models
from rmi_learn.data.dataset import load_dataset
from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.errors import InputError
from rmi_learn.planning.cost import CostWeights, clip_forces
from rmi_learn.planning.planner import Planner
from rmi_learn.planning.refine import METRICS, refine_chunk
from rmi_learn.planning.scorers import Scorer, world_model_scorer
from rmi_learn.planning.standardiser import WATER, Standardiser, stats_close
from rmi_learn.policies.checkpoint import load_policy
from rmi_learn.policies.fast_sampler import FastSampler, Objective
from rmi_learn.policies.unet import PolicyUNet
from rmi_learn.world_models.common import N_OBS, N_U, last_z


class RealtimePlanner(Planner):
    """:class:`~rmi_learn.planning.planner.Planner` on the fast sampling path: the same
    arguments, the same K samples for the same noise, the same cost and selection.

    ``steps`` overrides the objective's sampler step count (a distilled student's run
    records its own); ``threads`` sets ``torch.set_num_threads`` (process-wide) when given.
    ``refine``: a metric of :func:`rmi_learn.planning.refine.refine_chunk` (``smooth`` or
    ``l2``) with which :meth:`act` moves the selected chunk toward the goal by the scorer's
    gradient (``refine_iterations`` Gauss-Newton steps, setpoints kept within
    [min(u, ``refine_floor``), ``force_limit``] N); None selects only. :meth:`act` is the
    controller's call.
    """

    def __init__(
        self,
        policy: PolicyUNet,
        objective: Objective,
        scorer: Scorer,
        standardiser: Standardiser,
        k: int = 8,
        weights: CostWeights | None = None,
        force_limit: float = FORCE_LIMIT_N,
        steps: int | None = None,
        threads: int | None = None,
        refine: str | None = None,
        refine_iterations: int = 4,
        refine_floor: float = 0.0,
    ) -> None:
        if refine is not None and refine not in METRICS:
            raise InputError(f"refine must be one of {METRICS} or None, got {refine!r}")
        if threads is not None:
            torch.set_num_threads(threads)
        super().__init__(policy, objective, scorer, standardiser, k, weights, force_limit)
        self.sampler = FastSampler(policy, objective, steps)
        self.refine, self.refine_iterations = refine, refine_iterations
        self.refine_floor = refine_floor

    @property
    def steps(self) -> int:
        """Network evaluations per decision."""
        return self.sampler.schedule.steps

    def sample(
        self,
        hist: Tensor,
        hist_mask: Tensor,
        goal: Tensor,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """K clipped physical chunks per window: (B, K, H, 2), as :meth:`Planner.sample`."""
        cfg = self.policy.config
        chunks = self.sampler.sample(hist, hist_mask, goal, self.k, generator)
        phys = clip_forces(self.std.u_to_phys(chunks), self.force_limit)
        return phys.view(hist.shape[0], self.k, cfg.horizon, cfg.action_dim)

    #: :meth:`Planner.plan` in inference mode (same arguments and result).
    plan = torch.inference_mode()(Planner.plan)

    def act(
        self,
        hist: Tensor,
        hist_mask: Tensor,
        goal_kg: float | Tensor,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """One decision for one window: the selected chunk (H, 1) of force setpoints in N,
        refined toward the goal when the planner was made with ``refine``.

        ``hist``/``hist_mask`` (L, 23) are the latest L observation rows and their mask,
        standardised as in the dataset windows (the current M_L is read from the last row);
        ``goal_kg`` is the retained water to reach at the end of the chunk, in kg.
        """
        h, m = hist[None], hist_mask[None]
        goal = torch.as_tensor(goal_kg, dtype=torch.float32).reshape(1)
        goal_std = (goal - self.std.z_mean[WATER]) / self.std.z_std[WATER]
        res = self.plan(h, m, goal_std, last_z(h)[:, WATER], None, generator)
        chunk = res.selected[0]
        if self.refine is None:
            return chunk
        # The plan's tensors are inference tensors; gradients need ordinary copies.
        with torch.inference_mode(False):
            u = chunk.clone()[None]
            r = refine_chunk(
                self.scorer,
                self.std,
                h.clone(),
                m.clone(),
                u,
                goal.clone(),
                lower=torch.clamp(u, max=self.refine_floor),
                upper=self.force_limit,
                iterations=self.refine_iterations,
                metric=self.refine,
            )
        return r.u[0]


def load_realtime_planner(
    policy: str | Path,
    wm: str | Path,
    *,
    dataset: str | Path | None = None,
    k: int = 8,
    steps: int | None = None,
    threads: int | None = None,
    weights: str = "model.ema",
    force_limit: float = FORCE_LIMIT_N,
    refine: str | None = None,
    refine_floor: float = 0.0,
) -> RealtimePlanner:
    """A :class:`RealtimePlanner` from a policy run (trained or distilled) and a world-model
    run (the 32-step Linear-ARX, an AC-GRU-WM run for the native rollout, or W_T);
    ``refine`` and ``refine_floor`` as in :class:`RealtimePlanner`.

    The standardisation statistics come from the world model's run (``extra.stats``) or
    from ``dataset``; when both exist they must agree. Raises
    :class:`~rmi_learn.errors.InputError` for a directory that is not a policy or world-model
    run, damaged or mismatched weights, missing statistics, or a world model whose horizon
    or observation channels do not fit the policy.
    """
    try:
        net, objective, _ = load_policy(policy, weights)
        wm_net, wm_cfg = models.load(wm, observation_mode="privileged")
    except (FileNotFoundError, NotADirectoryError, KeyError, TypeError, ValueError) as exc:
        raise InputError(exc) from exc
    cfg = net.config
    if cfg.obs_dim != N_OBS or cfg.action_dim != N_U:
        raise InputError(
            f"{policy}: the policy sees {cfg.obs_dim} observation and {cfg.action_dim} action "
            f"channels, the world model {wm} {N_OBS} and {N_U}"
        )
    try:
        wm_net.check_horizon_length(cfg.horizon)
    except ValueError as exc:
        raise InputError(f"--wm {wm}: {exc} (the policy's chunks have {cfg.horizon})") from exc
    wm_stats = (wm_cfg.get("extra") or {}).get("stats")
    if dataset is not None:
        ds_stats = load_dataset(dataset).stats
        if wm_stats is not None and not stats_close(ds_stats, wm_stats):
            raise InputError(f"{wm} was trained with other statistics than {dataset}")
        std = Standardiser.from_stats(ds_stats)
    elif wm_stats is not None:
        try:
            std = Standardiser.from_stats(_Namespace(wm_stats))
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{wm}: unreadable standardisation statistics ({exc})") from exc
    else:
        raise InputError(
            f"no standardisation statistics: {wm} does not record them; pass the dataset"
        )
    return RealtimePlanner(
        net,
        objective,
        world_model_scorer(wm_net),
        std,
        k=k,
        force_limit=force_limit,
        steps=steps,
        threads=threads,
        refine=refine,
        refine_floor=refine_floor,
    )


class _Namespace:
    """Attribute access to a statistics dict (``z_mean`` ...), for
    :meth:`Standardiser.from_stats`."""

    def __init__(self, d: dict[str, Any]) -> None:
        for key in ("z_mean", "z_std", "u_mean", "u_std"):
            setattr(self, key, d[key])


__all__ = ["RealtimePlanner", "load_realtime_planner"]
