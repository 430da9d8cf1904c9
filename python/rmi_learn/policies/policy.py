"""A policy run directory as files: its standardisation statistics and the world model
stored with it.

A policy run directory (``rmi train-policy``) holds everything needed to act:

- ``config.json``: the network (``model``) and, in ``extra.stats``, the standardisation
  statistics of the training split (``Stats.to_json()`` of the dataset: means and standard
  deviations of the 18 continuous observation channels z, the M_L statistics among them,
  and of the action channels, with the channel names);
- ``model.ema.safetensors`` (sampling weights) and ``model.safetensors``;
- optionally ``world_model/``, a copy of the world-model run that ranks the samples
  (``config.json`` and ``model.safetensors``; written by ``rmi train-policy --wm`` or
  :func:`attach_world_model`).

The trained policy as one object that acts (:func:`rmi_learn.planning.policy.load_policy`)
is built from these.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from rmi_learn import world_models as models
from rmi_learn.data.dataset import Stats, load_dataset
from rmi_learn.data.schema import CONTINUOUS
from rmi_learn.errors import InputError
from rmi_learn.policies.checkpoint import load_policy as load_network

#: ``load_policy(..., scorer=STORED)``: rank with the world model stored in the run.
STORED = "stored"
#: Sub-directory of a policy run that holds its world model.
WORLD_MODEL_DIR = "world_model"
#: Files of a world-model run that loading it needs.
_WM_FILES = ("config.json", "model.safetensors")
_STAT_KEYS = ("z_mean", "z_std", "u_mean", "u_std")


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
    them (the network's output width). Means must be finite, standard deviations finite
    and positive (:meth:`~rmi_learn.data.dataset.Stats.check`). Raises
    :class:`~rmi_learn.errors.InputError` naming ``where`` otherwise.
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
    stats = Stats(**arrays)
    try:
        stats.check()
    except ValueError as exc:
        raise InputError(f"{where}: {exc}") from exc
    return stats, u_names


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
    try:
        from_dataset = load_dataset(dataset).stats.to_json()
    except (FileNotFoundError, ValueError) as exc:
        raise InputError(exc) from exc
    check_trained_on(run_dir, config, from_dataset, dataset)
    return from_dataset


def check_trained_on(
    run_dir: str | os.PathLike[str],
    config: Mapping[str, Any],
    dataset_stats: Mapping[str, Any],
    dataset: Any,
) -> None:
    """Refuse a policy run (its ``config.json`` is ``config``) whose stored statistics are
    not those of the dataset ``dataset`` (its ``Stats.to_json()`` is ``dataset_stats``): its
    network would be fed inputs standardised by other statistics. A run written before
    the statistics were stored cannot be checked and passes. Raises
    :class:`~rmi_learn.errors.InputError` naming both."""
    extra = config.get("extra") or {}
    stored = extra.get("stats") if isinstance(extra, Mapping) else None
    if stored is not None and not _same_stats(stored, dataset_stats):
        raise InputError(f"{run_dir} was trained with other statistics than {dataset}")


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
    try:
        net, cfg = models.load(Path(wm_dir), observation_mode="privileged")
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


__all__ = [
    "STORED",
    "WORLD_MODEL_DIR",
    "attach_world_model",
    "check_trained_on",
    "check_world_model",
    "parse_stats",
    "run_stats",
]
