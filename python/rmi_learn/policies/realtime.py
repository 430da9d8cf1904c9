"""Real-time decision path: K policy samples and their world-model scores within one 20 ms
control period on a CPU.

The reference path (:class:`~rmi_learn.policies.ranking.Planner` with the objective's own
sampler) is kept unchanged for the paper's tables. This module computes the same samples
with less work per decision:

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
chunks to float32 rounding (``tests/policies/test_realtime.py``). Few-step students
(:mod:`rmi_learn.policies.distill`) use the same path with 1 or 2 steps.

:class:`RealtimePlanner` wraps the sampler, a scorer (the native AC-GRU-WM rollout by
default in :func:`load_realtime_planner`, W_T on request) and the paper's cost into an
``act(hist, hist_mask, goal_kg) -> chunk`` call for a receding-horizon controller.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.errors import InputError
from rmi_learn.policies.diffusion import DiffusionObjective, ddim_step_pairs
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.ranking import (
    WATER,
    CostWeights,
    Planner,
    Scorer,
    Standardiser,
    clip_forces,
    world_model_scorer,
)
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
        noise is drawn as :meth:`Planner.sample` draws it."""
        cfg = self.net.config
        with torch.inference_mode():
            obs_cond = self.net.encode_condition(hist, hist_mask, goal)
            shape = (hist.shape[0] * k, cfg.horizon, cfg.action_dim)
            noise = torch.randn(shape, generator=generator).to(hist.device)
            return self.sample_from_condition(obs_cond, noise)


class RealtimePlanner(Planner):
    """:class:`~rmi_learn.policies.ranking.Planner` on the fast sampling path: the same
    arguments, the same K samples for the same noise, the same cost and selection.

    ``steps`` overrides the objective's sampler step count (a distilled student's run
    records its own); ``threads`` sets ``torch.set_num_threads`` (process-wide) when given.
    ``refine``: a metric of :func:`rmi_learn.control.refine.refine_chunk` (``smooth`` or
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
        from rmi_learn.control.refine import METRICS

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
        from rmi_learn.world_models.common import last_z

        h, m = hist[None], hist_mask[None]
        goal = torch.as_tensor(goal_kg, dtype=torch.float32).reshape(1)
        goal_std = (goal - self.std.z_mean[WATER]) / self.std.z_std[WATER]
        res = self.plan(h, m, goal_std, last_z(h)[:, WATER], None, generator)
        chunk = res.selected[0]
        if self.refine is None:
            return chunk
        from rmi_learn.control.refine import refine_chunk

        # The plan's tensors are inference tensors; gradients need ordinary copies.
        with torch.inference_mode(False):
            u = chunk.clone()[None]
            r = refine_chunk(
                self.scorer, self.std, h.clone(), m.clone(), u, goal.clone(),
                lower=torch.clamp(u, max=self.refine_floor), upper=self.force_limit,
                iterations=self.refine_iterations, metric=self.refine,
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
    from rmi_learn import world_models as models
    from rmi_learn.policies.checkpoint import load_policy
    from rmi_learn.policies.ranking import _stats_close
    from rmi_learn.world_models.common import N_OBS, N_U

    try:
        net, objective, _ = load_policy(policy, weights)
        wm_net, wm_cfg = models.load(wm)
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
        from rmi_learn.data.dataset import load_dataset

        ds_stats = load_dataset(dataset).stats
        if wm_stats is not None and not _stats_close(ds_stats, wm_stats):
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


__all__ = [
    "FastSampler",
    "RealtimePlanner",
    "Schedule",
    "load_realtime_planner",
    "mish",
    "schedule",
]
