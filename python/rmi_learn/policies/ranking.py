"""World-model ranking of policy samples (paper Sec. IV.C, Eq. rank), and the ranking stage
that writes Tables III, V and S1 (:func:`rank`, ``rmi rank``).

For every window, K = 8 chunks are drawn from the policy in one batch, converted to physical
units, force-limited to [0, FORCE_LIMIT_N] (the gripper's limit in N), scored by the causal
world model W_T, and the chunk with the smallest combined cost is selected::

    J = 1 * J_M + 1e-4 * J_F + 0.05 * J_S + 0.1 * J_U

with (our concrete definitions; the paper names the terms only):

- ``J_M`` (g): ``|M_hat^L_{t+H_pi} - g_t|``, the world model's terminal retained water after the
  last command of the chunk against the goal, in grams.
- ``J_F`` (N): peak commanded force ``max_tau F_target``.
- ``J_S`` (-): predicted slip probability, the mean over the horizon of
  ``P(slip) + P(mixed)`` from the friction head (mixed contact contains slipping particles).
- ``J_U``: action jerk, the mean over the chunk of the absolute second difference of the
  force setpoint in N per step^2.

The same cost is computed for the original (collected) chunk, which is never clipped. All
chunks are returned in physical units (N) so closed-loop execution can reuse them.

:func:`rank` runs the planner over every window of a dataset split (per sponge size; the
goal g is the collected M_L at t + 32) for each given policy and writes to its output
directory:

- ``table3_ranking.{md,json}``: W_T-predicted terminal water error |M_hat - g| in grams for
  the original chunk, the first sample and the selected sample, per size and objective.
- ``table5_imitation.{md,json}``: force MAE of the first sample against the original chunk and
  its mean absolute force change per step (smooth_F), in N.
- ``tableS1_cost.{md,json}``: combined predicted cost J.
- ``chunks_<objective>.npz``: per window the run, anchor row, goal, the original, first and
  selected chunks in physical units (N), the selected index and every sample's J, for
  closed-loop execution.

All errors are the scorer's own predictions (biased toward the scorer that selected the
chunk); closed-loop execution in the simulator gives the real error.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from rmi_learn.data.schema import CONTROL_ACTIONS, FORCE_LIMIT_N, FRICTION_CLASSES, SPONGE_SIZES_CM
from rmi_learn.errors import InputError
from rmi_learn.policies.diffusion import DiffusionObjective
from rmi_learn.policies.flow import FlowObjective
from rmi_learn.policies.unet import PolicyUNet

#: Sponge sizes of the tables (cm) and the tables' names of the objectives.
SIZES: tuple[int, ...] = SPONGE_SIZES_CM
LABELS = {"diffusion": "Diffusion policy", "flow": "Flow matching"}
#: Index of F_target in the action vector, and of M_L in the continuous state.
FORCE, WATER = CONTROL_ACTIONS.index("F_target"), 0
#: Friction classes counted as slipping (indices into FRICTION_CLASSES: none/stick/slip/mixed).
SLIP_CLASSES = (FRICTION_CLASSES.index("slip"), FRICTION_CLASSES.index("mixed"))

#: ``scorer(hist, hist_mask, actions_std) -> (z_std (N,H,18), p_contact (N,H), p_fric (N,H,4))``
Scorer = Callable[[Tensor, Tensor, Tensor], tuple[Tensor, Tensor, Tensor]]


@dataclass(frozen=True)
class CostWeights:
    """Weights of the combined cost (paper values). ``disagreement`` weighs ``J_D``, the
    spread of an ensemble's water forecasts (zero for a single scorer)."""

    water: float = 1.0
    force: float = 1e-4
    slip: float = 0.05
    jerk: float = 0.1
    disagreement: float = 1.0


@dataclass(frozen=True)
class Standardiser:
    """Training-split mean/std of the 18 continuous channels and the force setpoint (SI)."""

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
        """Standardised actions (..., 1) -> N."""
        return u * self.u_std + self.u_mean

    def u_to_std(self, u: Tensor) -> Tensor:
        """Physical actions (..., 1) in N -> standardised."""
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


# --------------------------------------------------------------------------------------
# The ranking stage: Tables III, V and S1


def _fmt(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.2f}"


def _markdown(title: str, header: list[str], rows: list[list[str]]) -> str:
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |"]
    lines.append("|" + "|".join(["---"] + [":---:"] * (len(header) - 1)) + "|")
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _write(out: Path, stem: str, md: str, payload: dict[str, Any]) -> None:
    (out / f"{stem}.md").write_text(md, encoding="utf-8")
    (out / f"{stem}.json").write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")


def _stats_close(a: Any, b: Any) -> bool:
    import numpy as np

    return all(
        np.allclose(np.asarray(getattr(a, k)), np.asarray(b[k]), rtol=1e-6, atol=0.0)
        for k in ("z_mean", "z_std", "u_mean", "u_std")
    )


def rank(
    data: str | Path,
    wm: str | Path,
    out: str | Path,
    *,
    diffusion: str | Path | None = None,
    flow: str | Path | None = None,
    split: str = "test",
    k: int = 8,
    max_windows: int = 0,
    batch_size: int = 64,
    seed: int = 0,
    force_limit: float = FORCE_LIMIT_N,
    weights: str = "model.ema",
    device: str = "cpu",
) -> dict[str, Any]:
    """``rmi rank``: rank ``k`` samples of each given policy run (``diffusion``, ``flow``)
    per window of ``split`` with the world model run ``wm`` and write Tables III, V, S1 and
    the ranked chunks into ``out`` (see the module docstring). ``max_windows``: per size,
    an evenly spaced subset (0: all); ``force_limit`` (N) clips the samples; ``weights``
    names the policy weights file stem. Returns ``{"out", "n_windows", "seconds"}``.

    Every input is checked before ``out`` is created: a missing policy, a world model whose
    horizon does not fit the policies' chunks or statistics that differ from the dataset's
    raise :class:`~rmi_learn.errors.InputError`.
    """
    import numpy as np

    from rmi_learn import world_models as models
    from rmi_learn.data.dataset import load_dataset
    from rmi_learn.policies.checkpoint import goal_from_batch, load_policy

    out = Path(out)
    policies = {n: p for n, p in (("diffusion", diffusion), ("flow", flow)) if p}
    if not policies:
        raise InputError("give --diffusion and/or --flow")
    # Every input is loaded and checked before --out exists: a wrong directory, model kind
    # or horizon is a one-line error, not a traceback after half the work.
    try:
        ds = load_dataset(data)
        wm_net, wm_cfg = models.load(wm)
        loaded = {n: load_policy(p, weights, device) for n, p in policies.items()}
        for name, (net, _, _) in loaded.items():
            h = net.config.horizon
            try:
                wm_net.check_horizon_length(h)
            except ValueError:
                fixed, longest = wm_net.fixed_horizon, wm_net.max_horizon
                takes = f"exactly {fixed}" if fixed is not None else f"at most {longest}"
                raise ValueError(
                    f"--wm {wm}: the {wm_net.kind} world model scores chunks of {takes} "
                    f"steps, the --{name} policy's have {h}"
                ) from None
    except ValueError as exc:
        raise InputError(exc) from exc
    wm_net = wm_net.to(device)
    wm_stats = (wm_cfg.get("extra") or {}).get("stats")
    if wm_stats is not None and not _stats_close(ds.stats, wm_stats):
        raise InputError("W_T was trained with other standardisation statistics")
    std = Standardiser.from_stats(ds.stats)
    std = Standardiser(*(x.to(device) for x in (std.z_mean, std.z_std, std.u_mean, std.u_std)))
    scorer = world_model_scorer(wm_net)
    out.mkdir(parents=True, exist_ok=True)
    sizes = [s for s in SIZES if len(ds.split_runs(split, s)) > 0]

    # results[source][size] -> dict of per-window arrays
    per: dict[str, dict[int, dict[str, np.ndarray]]] = {}
    n_windows: dict[int, int] = {}
    timing: dict[str, float] = {}
    for obj_name, (net, objective, pcfg) in loaded.items():
        planner = Planner(net, objective, scorer, std, k=k, force_limit=force_limit)
        t0 = time.perf_counter()
        per[obj_name] = {}
        chunks: dict[str, list[np.ndarray]] = {}
        for size in sizes:
            ws = ds.windows(
                split,
                size,
                history=int(pcfg["model"]["history"]),
                horizon=net.config.horizon,
            )
            idx = np.arange(len(ws))
            if max_windows and len(ws) > max_windows:
                idx = np.unique(np.linspace(0, len(ws) - 1, max_windows).round()).astype(np.int64)
            n_windows[size] = int(idx.size)
            gen = torch.Generator().manual_seed(seed * 1000 + size)
            acc: dict[str, list[np.ndarray]] = {}
            for start in range(0, idx.size, batch_size):
                b = ws.batch(idx[start : start + batch_size])
                b = {n: v.to(device) for n, v in b.items()}
                g_std, _ = goal_from_batch(b)
                res = planner.plan(
                    b["hist"], b["hist_mask"], g_std, b["water_now"], b["actions"], gen
                )
                assert res.original is not None
                first, sel, orig = res.first, res.selected, res.original
                cols: dict[str, torch.Tensor] = {
                    "orig_JM": res.original_costs["J_M"],
                    "orig_J": res.original_costs["J"],
                    "first_JM": res.first_costs()["J_M"],
                    "first_J": res.first_costs()["J"],
                    "sel_JM": res.selected_costs()["J_M"],
                    "sel_J": res.selected_costs()["J"],
                    "mae_F": (first[..., 0] - orig[..., 0]).abs().mean(-1),
                    "smooth_F": first[..., 0].diff(dim=-1).abs().mean(-1),
                    "orig_smooth_F": orig[..., 0].diff(dim=-1).abs().mean(-1),
                    "sel_mae_F": (sel[..., 0] - orig[..., 0]).abs().mean(-1),
                }
                for key, v in cols.items():
                    acc.setdefault(key, []).append(v.cpu().numpy())
                water_now_kg = std.water_to_kg(b["water_now"])
                for key, v in {
                    "size_cm": torch.full_like(res.goal_kg, float(size)),
                    "run": b["run"],
                    "t": b["t"],
                    "goal_kg": res.goal_kg,
                    "water_now_kg": water_now_kg,
                    "original": orig,
                    "first": first,
                    "selected": sel,
                    "index": res.index,
                    "J_samples": res.costs["J"],
                    "J_M_samples": res.costs["J_M"],
                }.items():
                    chunks.setdefault(key, []).append(v.cpu().numpy())
            per[obj_name][size] = {key: np.concatenate(v) for key, v in acc.items()}
        timing[obj_name] = time.perf_counter() - t0
        arrays = {key: np.concatenate(v) for key, v in chunks.items()}
        arrays["size_cm"] = arrays["size_cm"].astype(np.int64)
        arrays["run_id"] = np.asarray([ds.run_ids[int(r)] for r in arrays["run"]])
        np.savez_compressed(out / f"chunks_{obj_name}.npz", **arrays)  # type: ignore[arg-type]

    def mean(obj: str, size: int, key: str) -> float | None:
        d = per.get(obj, {}).get(size)
        return None if d is None or d[key].size == 0 else float(d[key].mean())

    first_obj = next(iter(policies))
    header = ["Method"] + [f"{s} cm" for s in SIZES]

    def row(label: str, obj: str, key: str) -> tuple[list[str], dict[str, Any]]:
        vals = {str(s): mean(obj, s, key) for s in SIZES}
        return [label] + [_fmt(vals[str(s)]) for s in SIZES], {"method": label, **vals}

    common = {
        "split": split,
        "k": k,
        "n_windows": {str(s): n_windows.get(s, 0) for s in SIZES},
        "scorer": str(wm),
        "policies": {n: str(v) for n, v in policies.items()},
        "note": "predicted by the scorer W_T that selects the chunk (biased toward it)",
    }

    def source_rows(metric: str) -> tuple[list[list[str]], list[dict[str, Any]]]:
        """Rows of one metric for the original action, each first sample and each selection
        (Tables III and S1 share this layout)."""
        sources = [("Original controller action", first_obj, f"orig_{metric}")] + [
            item
            for o in policies
            for item in (
                (f"{LABELS[o]}, first sample", o, f"first_{metric}"),
                (f"{LABELS[o]} + W_T", o, f"sel_{metric}"),
            )
        ]
        built = [row(label, obj, key) for label, obj, key in sources]
        return [m for m, _ in built], [j for _, j in built]

    # Table III
    md_rows, js_rows = source_rows("JM")
    _write(
        out,
        "table3_ranking",
        _markdown(
            "Table III. W_T-predicted terminal water error |M_hat - g| (g), K = "
            f"{k}, {split} split",
            header,
            md_rows,
        ),
        {"table": "III", "unit": "g", "rows": js_rows, **common},
    )

    # Table V
    header5 = ["Method"] + [f"{s} cm {q}" for s in SIZES for q in ("MAE_F (N)", "smooth_F (N)")]
    md5, js5 = [], []
    for o in policies:
        vals = {
            str(s): {"MAE_F": mean(o, s, "mae_F"), "smooth_F": mean(o, s, "smooth_F")}
            for s in SIZES
        }
        md5.append(
            [LABELS[o]] + [_fmt(vals[str(s)][q]) for s in SIZES for q in ("MAE_F", "smooth_F")]
        )
        js5.append({"method": LABELS[o], **vals})
    ref = {str(s): {"MAE_F": 0.0, "smooth_F": mean(first_obj, s, "orig_smooth_F")} for s in SIZES}
    md5.append(
        ["Original controller action (reference)"]
        + [
            _fmt(ref[str(s)][q]) if q == "smooth_F" else "-"
            for s in SIZES
            for q in ("MAE_F", "smooth_F")
        ]
    )
    js5.append({"method": "Original controller action (reference)", **ref})
    _write(
        out,
        "table5_imitation",
        _markdown(
            "Table V. Force MAE of one policy sample against the collected command and its "
            "mean absolute force change per step (N)",
            header5,
            md5,
        ),
        {"table": "V", "unit": "N", "rows": js5, **common},
    )

    # Table S1
    mds, jss = source_rows("J")
    _write(
        out,
        "tableS1_cost",
        _markdown(
            "Table S1. Combined predicted cost J = J_M + 1e-4 J_F + 0.05 J_S + 0.1 J_U",
            header,
            mds,
        ),
        {"table": "S1", "unit": "-", "rows": jss, **common},
    )
    return {"out": str(out), "n_windows": common["n_windows"], "seconds": timing}
