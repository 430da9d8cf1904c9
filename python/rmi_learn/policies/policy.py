"""A trained policy as one object: raw physical observations in, physical actions out.

A policy run directory (``rmi train-policy``) holds everything needed to act:

- ``config.json``: the network (``model``) and, in ``extra.stats``, the standardisation
  statistics of the training split (``Stats.to_json()`` of the dataset: means and standard
  deviations of the 18 continuous observation channels z, the M_L statistics among them,
  and of the action channels, with the channel names);
- ``model.ema.safetensors`` (sampling weights) and ``model.safetensors``;
- optionally ``world_model/``, a copy of the world-model run that ranks the samples
  (``config.json`` and ``model.safetensors``; written by ``rmi train-policy --wm`` or
  :func:`attach_world_model`).

:func:`load_policy` turns such a directory into a :class:`Policy`; moving or copying the
directory keeps it working, the dataset is not needed. :meth:`Policy.act` takes the latest
observation rows in SI units (``schema.OBS`` order, NaN where a value is undefined) and the
goal retained water in kg, and returns the next action chunk in SI units. Sampling and
ranking are the project's own paths: :class:`~rmi_learn.policies.ranking.Planner` (or
:class:`~rmi_learn.policies.realtime.RealtimePlanner` with ``realtime=True``) draws the
samples and, with a world model, scores them with the paper's cost and selects one.
"""

from __future__ import annotations

import math
import os
import shutil
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from rmi_learn.data.dataset import Stats
from rmi_learn.data.schema import CONTINUOUS, CONTINUOUS_INDEX, OBS
from rmi_learn.errors import InputError
from rmi_learn.policies.ranking import WATER, Planner, PlanResult, Scorer, Standardiser
from rmi_learn.world_models.common import last_z

#: ``load_policy(..., scorer=STORED)``: rank with the world model stored in the run.
STORED = "stored"
#: Sub-directory of a policy run that holds its world model.
WORLD_MODEL_DIR = "world_model"
#: Files of a world-model run that loading it needs.
_WM_FILES = ("config.json", "model.safetensors")
_STAT_KEYS = ("z_mean", "z_std", "u_mean", "u_std")
_ML = OBS.index("M_L")


# --------------------------------------------------------------------------------------
# Statistics


def _stats_arrays(d: Any, where: str) -> dict[str, np.ndarray]:
    """The four statistics arrays of a ``Stats.to_json()`` dict (InputError naming
    ``where`` if one is missing or not a list of numbers)."""
    if not isinstance(d, Mapping):
        raise InputError(f"{where}: standardisation statistics must be a JSON object")
    out = {}
    for key in _STAT_KEYS:
        try:
            out[key] = np.asarray(d[key], dtype=np.float64).reshape(-1)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: statistics field {key!r} missing or not numbers") from exc
    return out


def parse_stats(d: Any, action_dim: int, where: str) -> tuple[Stats, tuple[str, ...]]:
    """Statistics and action channel names from a ``Stats.to_json()`` dict.

    The observation channels must be ``schema.CONTINUOUS`` (the policy reads the history in
    that order); the action channels are whatever the run was trained on, ``action_dim`` of
    them (the network's output width). Standard deviations must be finite and positive.
    Raises :class:`~rmi_learn.errors.InputError` naming ``where`` otherwise.
    """
    arrays = _stats_arrays(d, where)
    z_names = list(d.get("z_names", CONTINUOUS))
    if z_names != list(CONTINUOUS):
        raise InputError(f"{where}: statistics of observation channels {z_names}, expected "
                         f"{list(CONTINUOUS)}")  # fmt: skip
    if arrays["z_mean"].size != len(CONTINUOUS) or arrays["z_std"].size != len(CONTINUOUS):
        raise InputError(f"{where}: z statistics need {len(CONTINUOUS)} values per field")
    if "u_names" not in d:
        raise InputError(f"{where}: statistics lack the action channel names (u_names)")
    u_names = tuple(str(n) for n in d["u_names"])
    if not (len(u_names) == arrays["u_mean"].size == arrays["u_std"].size == action_dim):
        raise InputError(
            f"{where}: statistics of {len(u_names)} action channels {list(u_names)}, the "
            f"network outputs {action_dim}"
        )
    for key in ("z_std", "u_std"):
        if not np.all(np.isfinite(arrays[key]) & (arrays[key] > 0)):
            raise InputError(f"{where}: statistics field {key!r} must be finite and > 0")
    return Stats(**arrays), u_names


def _same_stats(a: Any, b: Any) -> bool:
    """Whether two statistics dicts hold the same arrays (shapes equal, values to 1e-6)."""
    try:
        pa, pb = _stats_arrays(a, "a"), _stats_arrays(b, "b")
    except InputError:
        return False
    return all(
        pa[k].shape == pb[k].shape and np.allclose(pa[k], pb[k], rtol=1e-6, atol=0.0)
        for k in _STAT_KEYS
    )


def run_stats(
    run_dir: str | os.PathLike[str], config: Mapping[str, Any], dataset: Any = None
) -> dict[str, Any]:
    """The statistics JSON of a policy run: ``config["extra"]["stats"]``, or, for a run
    written before they were stored, those of ``dataset`` (a built dataset directory).

    When both exist they must agree. Raises :class:`~rmi_learn.errors.InputError` for a
    run without statistics and no ``dataset`` (retrain it, or pass the dataset it was
    trained on).
    """
    extra = config.get("extra") or {}
    stored = extra.get("stats") if isinstance(extra, Mapping) else None
    if dataset is None:
        if stored is None:
            data = extra.get("data") if isinstance(extra, Mapping) else None
            trained = f" (it was trained on {data})" if data else ""
            raise InputError(
                f"{run_dir} does not store its standardisation statistics: retrain it with "
                f"this version of rmi train-policy, or pass the dataset it was trained "
                f"on{trained} as dataset="
            )
        return dict(stored)
    from rmi_learn.data.dataset import load_dataset

    try:
        from_dataset = load_dataset(dataset).stats.to_json()
    except (FileNotFoundError, ValueError) as exc:
        raise InputError(exc) from exc
    if stored is not None and not _same_stats(stored, from_dataset):
        raise InputError(f"{run_dir} was trained with other statistics than {dataset}")
    return from_dataset


# --------------------------------------------------------------------------------------
# The world model of a run


def check_world_model(
    wm_dir: str | os.PathLike[str], stats: Mapping[str, Any], horizon: int
) -> tuple[torch.nn.Module, dict[str, Any]]:
    """Load the world-model run ``wm_dir`` and check that it can rank chunks of a policy
    with statistics ``stats`` (a ``Stats.to_json()`` dict) and chunks of ``horizon``
    control steps. Returns (model in eval mode, its config.json).

    Raises :class:`~rmi_learn.errors.InputError` for a directory that is not a world-model
    run, a model that cannot forecast ``horizon`` steps, or one trained with other
    statistics or action channels.
    """
    from rmi_learn import world_models as models

    try:
        net, cfg = models.load(Path(wm_dir))
    except (FileNotFoundError, NotADirectoryError, KeyError, TypeError, ValueError) as exc:
        raise InputError(f"world model {wm_dir}: {exc}") from exc
    try:
        net.check_horizon_length(horizon)
    except ValueError as exc:
        raise InputError(
            f"world model {wm_dir}: {exc} (the policy's chunks have {horizon} steps)"
        ) from exc
    wm_stats = (cfg.get("extra") or {}).get("stats")
    if wm_stats is not None:
        names = wm_stats.get("u_names")
        if names is not None and list(names) != list(stats.get("u_names", names)):
            raise InputError(
                f"world model {wm_dir} takes actions {list(names)}, the policy gives "
                f"{list(stats['u_names'])}"
            )
        if not _same_stats(wm_stats, stats):
            raise InputError(
                f"world model {wm_dir} was trained with other standardisation statistics "
                "than the policy"
            )
    return net, cfg


def attach_world_model(policy_dir: str | os.PathLike[str], wm_dir: str | os.PathLike[str]) -> Path:
    """Copy the world-model run ``wm_dir`` into ``policy_dir/world_model`` (replacing one
    already there), after checking it fits the policy (:func:`check_world_model`); the
    policy run then ranks without outside files (``load_policy(..., scorer=STORED)``).
    Returns the copy's path. Raises :class:`~rmi_learn.errors.InputError` for a run
    without statistics or a world model that does not fit.
    """
    from rmi_learn.policies.checkpoint import load_policy as load_network

    policy_dir, wm_dir = Path(policy_dir), Path(wm_dir)
    try:
        net, _, cfg = load_network(policy_dir)
    except (FileNotFoundError, NotADirectoryError, KeyError, TypeError, ValueError) as exc:
        raise InputError(exc) from exc
    stats = run_stats(policy_dir, cfg)
    check_world_model(wm_dir, stats, net.config.horizon)
    dest = policy_dir / WORLD_MODEL_DIR
    # Copied under a temporary name and renamed, so a reader never sees half a model.
    tmp = policy_dir / f"{WORLD_MODEL_DIR}.tmp"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    for name in _WM_FILES:
        shutil.copy2(wm_dir / name, tmp / name)
    if dest.exists():
        shutil.rmtree(dest)
    tmp.rename(dest)
    return dest


def _unranked(hist: Tensor, hist_mask: Tensor, actions: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The scorer of a policy loaded without a world model: never called."""
    raise RuntimeError("this policy was loaded without a world model (scorer=None)")


def _scorer(
    scorer: Any, run_dir: Path, stats: Mapping[str, Any], horizon: int
) -> tuple[Scorer | None, str | None]:
    """The planner's scorer for ``load_policy(scorer=...)`` and a label of its source."""
    from rmi_learn.policies.ranking import world_model_scorer

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
    :class:`~rmi_learn.policies.ranking.Planner` that samples and ranks), ``config`` (the
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
    the world model stored in the run, see :func:`attach_world_model`), a world-model run
    directory, a world model (``torch.nn.Module``) or a
    :data:`~rmi_learn.policies.ranking.Scorer` function; with one, ``k`` samples are drawn
    per decision and the one with the smallest predicted cost is returned. ``realtime``
    uses the fast sampling path (:class:`~rmi_learn.policies.realtime.RealtimePlanner`,
    the same chunks to float32 rounding). ``seed`` seeds the sampling noise; ``dataset``
    supplies the statistics of a run written before they were stored; ``weights`` names the
    weights file (``model.ema`` or ``model``).

    Raises :class:`~rmi_learn.errors.InputError` for a directory that is not a policy run,
    damaged weights, missing or malformed statistics, or a world model that does not fit.
    """
    from rmi_learn.policies.checkpoint import load_policy as load_network
    from rmi_learn.policies.realtime import RealtimePlanner

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


__all__ = [
    "STORED",
    "WORLD_MODEL_DIR",
    "Policy",
    "attach_world_model",
    "check_world_model",
    "load_policy",
    "observation_row",
    "parse_stats",
    "run_stats",
]
