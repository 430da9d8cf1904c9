"""A trained policy as one object: raw physical observations in, physical actions out.

:func:`load_policy` turns a policy run directory (``rmi train-policy``; its files, statistics
and stored world model are described in :mod:`rmi_learn.policies.policy`) into a
:class:`Policy`; moving or copying the directory keeps it working, the dataset is not needed.
:meth:`Policy.act` takes the latest observation rows in SI units (``schema.OBS`` order, NaN
where a value is undefined) and the goal retained water in kg, and returns the next action
chunk in SI units. Sampling and
ranking are the project's own paths: :class:`~rmi_learn.planning.planner.Planner` (or
:class:`~rmi_learn.planning.realtime.RealtimePlanner` with ``realtime=True``) draws the
samples and, with a world model, scores them with the paper's cost and selects one.
"""

from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from rmi_learn.data.dataset import Stats
from rmi_learn.data.schema import CONTINUOUS_INDEX, OBS
from rmi_learn.errors import InputError
from rmi_learn.planning.planner import Planner, PlanResult
from rmi_learn.planning.realtime import RealtimePlanner
from rmi_learn.planning.scorers import Scorer, world_model_scorer
from rmi_learn.planning.standardiser import WATER, Standardiser
from rmi_learn.policies.checkpoint import load_policy as load_network
from rmi_learn.policies.policy import (
    STORED,
    WORLD_MODEL_DIR,
    check_world_model,
    parse_stats,
    run_stats,
)
from rmi_learn.world_models.common import last_z

_ML = OBS.index("M_L")


def _unranked(hist: Tensor, hist_mask: Tensor, actions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The scorer of a policy loaded without a world model: never called."""
    raise RuntimeError("this policy was loaded without a world model (scorer=None)")


def _scorer(
    scorer: Any, run_dir: Path, stats: Mapping[str, Any], horizon: int
) -> tuple[Scorer | None, str | None]:
    """The planner's scorer for ``load_policy(scorer=...)`` and a label of its source."""
    if scorer is None:
        return None, None
    if isinstance(scorer, torch.nn.Module):
        try:
            scorer.check_horizon_length(horizon)  # type: ignore[operator]
        except (AttributeError, ValueError) as exc:
            raise InputError(f"scorer: {exc}") from exc
        return world_model_scorer(scorer.eval()), type(scorer).__name__
    if isinstance(scorer, (str, os.PathLike)):
        if str(scorer) == STORED:
            wm_dir = run_dir / WORLD_MODEL_DIR
            if not wm_dir.is_dir():
                raise InputError(
                    f"{run_dir} stores no world model ({WORLD_MODEL_DIR}/); train it with "
                    "--wm or use attach_world_model, or pass a world-model run as scorer"
                )
        else:
            wm_dir = Path(scorer)
        net, _ = check_world_model(wm_dir, stats, horizon)
        return world_model_scorer(net), str(wm_dir)
    if callable(scorer):
        return scorer, getattr(scorer, "__name__", "scorer")
    raise InputError(
        f"scorer must be None, {STORED!r}, a world-model run directory or a scorer function, "
        f"got {type(scorer).__name__}"
    )


# --------------------------------------------------------------------------------------
# Observations


def observation_row(obs: Any, info: Mapping[str, Any] | None = None) -> np.ndarray:
    """One raw observation row (23,) float64 in ``schema.OBS`` order, NaN where undefined.

    ``obs`` is the Gymnasium environment's observation (23 values; it holds 0 where a value
    is undefined, and ``info["mask"]`` says where, so pass ``info``), or a mapping by channel
    name such as ``Trial.take_record()`` or ``info["y"]`` (None or NaN where undefined).
    """
    if isinstance(obs, Mapping):
        vals = [obs[n] for n in OBS]
        row = np.asarray([math.nan if v is None else float(v) for v in vals], dtype=np.float64)
    else:
        row = np.asarray(obs, dtype=np.float64).reshape(-1).copy()
    if row.shape != (len(OBS),):
        raise ValueError(f"an observation has {len(OBS)} values (schema.OBS), got {row.shape}")
    if info is not None and "mask" in info:
        mask = np.asarray(info["mask"], dtype=bool).reshape(-1)
        if mask.shape != row.shape:
            raise ValueError(f"info['mask'] must have {len(OBS)} entries, got {mask.shape}")
        row[~mask] = math.nan
    return row


# --------------------------------------------------------------------------------------
# The policy


class Policy:
    """A trained policy with its standardisation: :meth:`act` maps the latest physical
    observations and a goal retained water mass (kg) to an action chunk in SI units.

    Built by :func:`load_policy`. Attributes: ``action_names`` (the action channels, e.g.
    ``("F_target", "v_cmd")``: N and m/s), ``obs_names`` (``schema.OBS``),
    ``history_length`` L (rows the network sees), ``horizon`` H (rows of a chunk, 20 ms
    each), ``ranked`` (whether a world model selects among ``k`` samples), ``stats``
    (:class:`~rmi_learn.data.dataset.Stats`), ``planner`` (the
    :class:`~rmi_learn.planning.planner.Planner` that samples and ranks), ``config`` (the
    run's config.json), ``last_plan`` (the :class:`PlanResult` of the latest ranked
    decision: every sample, its cost and predicted M_L).

    Samples draw their noise from one generator seeded with ``seed``; :meth:`reset`
    reseeds it, so an episode's decisions repeat for the same observations.
    """

    def __init__(
        self,
        planner: Planner,
        stats: Stats,
        action_names: tuple[str, ...],
        history_length: int,
        *,
        ranked: bool,
        seed: int = 0,
        config: dict[str, Any] | None = None,
        scorer_source: str | None = None,
    ) -> None:
        if history_length < 1:
            raise ValueError(f"history_length must be >= 1, got {history_length}")
        self.planner = planner
        self.stats = stats
        self.action_names = tuple(action_names)
        self.obs_names: tuple[str, ...] = OBS
        self.history_length = int(history_length)
        self.horizon: int = planner.policy.config.horizon
        self.ranked = ranked
        self.k = planner.k
        self.seed = int(seed)
        self.config = config or {}
        self.scorer_source = scorer_source
        self.last_plan: PlanResult | None = None
        self.generator = torch.Generator()
        self._rows: deque[np.ndarray] = deque(maxlen=self.history_length)
        self.reset()

    def reset(self) -> None:
        """Start an episode: forget the observed rows and reseed the sampling noise."""
        self._rows.clear()
        self.generator.manual_seed(self.seed)
        self.last_plan = None

    def observe(self, obs: Any, info: Mapping[str, Any] | None = None) -> np.ndarray:
        """Append one observation (see :func:`observation_row`) to the history kept since
        :meth:`reset` and return the latest rows, (n, 23) with n <= L, for :meth:`act`."""
        self._rows.append(observation_row(obs, info))
        return np.stack(self._rows)

    def standardise(self, history: Any) -> tuple[Tensor, Tensor]:
        """The network's input for a raw history: (1, L, 23) values and validity mask.

        ``history`` (n, 23) in ``schema.OBS`` order and SI units, oldest row first, NaN
        where undefined; the last L rows are used, and fewer than L are preceded by copies
        of the first (the state before the first observation is taken as that state).
        Continuous channels are standardised with the training statistics, undefined
        values become 0 with mask 0, as in the dataset windows.
        """
        y = np.asarray(history, dtype=np.float64)
        if y.ndim != 2 or y.shape[0] < 1 or y.shape[1] != len(OBS):
            raise ValueError(
                f"history must be (n >= 1, {len(OBS)}) rows of schema.OBS values, "
                f"got shape {y.shape}"
            )
        y = y[-self.history_length :]
        if y.shape[0] < self.history_length:
            pad = np.repeat(y[:1], self.history_length - y.shape[0], axis=0)
            y = np.concatenate([pad, y])
        if not math.isfinite(y[-1, _ML]):
            raise ValueError(f"history: the last row's M_L (kg) must be finite, got {y[-1, _ML]}")
        mask = np.isfinite(y)
        ys = y.copy()
        ci = list(CONTINUOUS_INDEX)
        ys[:, ci] = self.stats.standardise_z(y[:, ci])
        ys[~mask] = 0.0
        hist = torch.from_numpy(ys.astype(np.float32))[None]
        return hist, torch.from_numpy(mask.astype(np.float32))[None]

    def act(self, history: Any, goal_kg: float) -> np.ndarray:
        """The next action chunk (H, n_actions) float32 in SI units (columns
        ``action_names``; forces limited to the gripper's range) for the raw ``history``
        (see :meth:`standardise`) and the retained water ``goal_kg`` (kg) to reach at the end
        of the chunk. Execute its first rows and call again (receding horizon).
        """
        goal = float(goal_kg)
        if not (math.isfinite(goal) and goal >= 0.0):
            raise ValueError(f"goal_kg must be a retained water mass >= 0 kg, got {goal_kg!r}")
        hist, mask = self.standardise(history)
        std = self.planner.std
        goal_t = torch.tensor([goal], dtype=torch.float32)
        goal_std = (goal_t - std.z_mean[WATER]) / std.z_std[WATER]
        water_now = last_z(hist)[:, WATER]
        with torch.inference_mode():
            if self.ranked:
                res = self.planner.plan(hist, mask, goal_std, water_now, None, self.generator)
                self.last_plan = res
                chunk = res.selected[0]
            else:
                cond = std.goal_vector(goal_std, water_now)
                chunk = self.planner.sample(hist, mask, cond, self.generator)[0, 0]
        out: np.ndarray = chunk.numpy().astype(np.float32, copy=True)
        return out


def load_policy(
    run_dir: str | os.PathLike[str],
    *,
    realtime: bool = False,
    scorer: Any = None,
    k: int = 8,
    seed: int = 0,
    dataset: str | os.PathLike[str] | None = None,
    weights: str = "model.ema",
) -> Policy:
    """A :class:`Policy` from a policy run directory (trained or distilled).

    ``scorer``: None (the policy alone: one sample per decision), :data:`STORED` (``"stored"``:
    the world model stored in the run, see
    :func:`~rmi_learn.policies.policy.attach_world_model`), a world-model run directory, a
    world model (``torch.nn.Module``) or a
    :data:`~rmi_learn.planning.scorers.Scorer` function; with one, ``k`` samples are drawn
    per decision and the one with the smallest predicted cost is returned. ``realtime``
    uses the fast sampling path (:class:`~rmi_learn.planning.realtime.RealtimePlanner`,
    the same chunks to float32 rounding). ``seed`` seeds the sampling noise; ``dataset``
    supplies the statistics of a run written before they were stored; ``weights`` names the
    weights file (``model.ema`` or ``model``).

    Raises :class:`~rmi_learn.errors.InputError` for a directory that is not a policy run,
    damaged weights, missing or malformed statistics, or a world model that does not fit.
    """
    run_dir = Path(run_dir)
    if k < 1:
        raise InputError(f"k must be at least 1 sample, got {k}")
    try:
        net, objective, cfg = load_network(run_dir, weights)
        history = int(cfg["model"]["history"])
    except (FileNotFoundError, NotADirectoryError, KeyError, TypeError, ValueError) as exc:
        raise InputError(exc) from exc
    stats_json = run_stats(run_dir, cfg, dataset)
    stats, names = parse_stats(stats_json, net.config.action_dim, f"{run_dir}")
    std = Standardiser.from_stats(stats)
    score, source = _scorer(scorer, run_dir, stats_json, net.config.horizon)
    n = k if score is not None else 1
    cls = RealtimePlanner if realtime else Planner
    planner = cls(net, objective, score or _unranked, std, k=n)
    return Policy(
        planner,
        stats,
        names,
        history,
        ranked=score is not None,
        seed=seed,
        config=cfg,
        scorer_source=source,
    )


__all__ = ["Policy", "load_policy", "observation_row"]
