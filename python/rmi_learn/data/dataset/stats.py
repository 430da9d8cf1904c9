"""Standardisation statistics of the continuous channels and the learned action."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.data.schema import (
    CONTINUOUS,
    CONTROL_ACTIONS,
)
from rmi_learn.errors import InputError

try:  # torch is in the `learn` extra; statistics of numpy arrays do not need it.
    import torch
except ImportError:  # pragma: no cover - exercised only without torch
    torch = None  # type: ignore[assignment]


@dataclass
class Stats:
    """Standardisation statistics from the training split: ``z_mean, z_std`` (18,) in the
    units of CONTINUOUS, ``u_mean, u_std`` (1,) in N (``CONTROL_ACTIONS``: F_target).
    ``*_std`` is the divisor used (population std, or 1 for a channel constant in training)."""

    z_mean: np.ndarray
    z_std: np.ndarray
    u_mean: np.ndarray
    u_std: np.ndarray

    @staticmethod
    def _apply(x: Any, scale: np.ndarray, shift: np.ndarray, inverse: bool) -> Any:
        if torch is not None and isinstance(x, torch.Tensor):
            s = torch.as_tensor(scale, dtype=x.dtype, device=x.device)
            m = torch.as_tensor(shift, dtype=x.dtype, device=x.device)
        else:
            arr = np.asarray(x)
            dtype = arr.dtype if np.issubdtype(arr.dtype, np.floating) else np.float64
            sa, ma = scale.astype(dtype), shift.astype(dtype)
            return arr * sa + ma if inverse else (arr - ma) / sa
        return x * s + m if inverse else (x - m) / s

    def standardise_z(self, x: Any) -> Any:
        """(x - z_mean) / z_std over the last axis (18 continuous channels)."""
        return self._apply(x, self.z_std, self.z_mean, inverse=False)

    def destandardise_z(self, x: Any) -> Any:
        """x * z_std + z_mean over the last axis: back to SI units (torch or numpy)."""
        return self._apply(x, self.z_std, self.z_mean, inverse=True)

    def standardise_u(self, x: Any) -> Any:
        """(u - u_mean) / u_std over the last axis (F_target, N)."""
        return self._apply(x, self.u_std, self.u_mean, inverse=False)

    def destandardise_u(self, x: Any) -> Any:
        """u * u_std + u_mean over the last axis: back to N (torch or numpy)."""
        return self._apply(x, self.u_std, self.u_mean, inverse=True)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict with channel names."""
        return {
            "z_names": list(CONTINUOUS),
            "u_names": list(CONTROL_ACTIONS),
            "z_mean": self.z_mean.tolist(),
            "z_std": self.z_std.tolist(),
            "u_mean": self.u_mean.tolist(),
            "u_std": self.u_std.tolist(),
        }

    def check(self) -> None:
        """Raise ValueError naming the field unless every mean is finite and every standard
        deviation finite and > 0: anything else turns the standardised rows into NaN or
        infinity, and a model trained or acting on them into NaN."""
        for key in ("z_mean", "u_mean"):
            if not np.all(np.isfinite(getattr(self, key))):
                raise ValueError(f"statistics field {key!r} must be finite")
        for key in ("z_std", "u_std"):
            value = getattr(self, key)
            if not np.all(np.isfinite(value) & (value > 0)):
                raise ValueError(f"statistics field {key!r} must be finite and > 0")

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Stats:
        """Inverse of :meth:`to_json`; refuses statistics of other channel names and values
        :meth:`check` refuses."""
        if list(d["z_names"]) != list(CONTINUOUS):
            raise ValueError("stats.json channel names differ from rmi_learn.data.schema")
        if list(d["u_names"]) != list(CONTROL_ACTIONS):
            raise ValueError(
                f"stats.json has actions {list(d['u_names'])}, this version learns "
                f"{list(CONTROL_ACTIONS)} (force setpoints): rebuild the dataset with "
                "`rmi dataset` and retrain the models on it"
            )
        stats = cls(
            *(np.asarray(d[k], dtype=np.float64) for k in ("z_mean", "z_std", "u_mean", "u_std"))
        )
        stats.check()
        return stats


def read_stats(path: Path) -> Stats:
    """The statistics file of a built dataset (``stats.json``, see :meth:`Stats.from_json`);
    one that is not the statistics of a built dataset of this version (another channel, a
    missing field, a value :meth:`Stats.check` refuses) raises
    :class:`~rmi_learn.errors.InputError` naming it."""
    d = json.loads(path.read_text())
    try:
        return Stats.from_json(d)
    except KeyError as exc:
        raise InputError(f"{path}: statistics field {exc} is missing") from exc
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from exc


def compute_stats(z: np.ndarray, u: np.ndarray) -> Stats:
    """Statistics of training rows ``z`` (N, 18) and ``u`` (N, 2); NaN ignored."""
    if z.shape[0] == 0:
        raise ValueError("no training rows to compute statistics from")

    def mean_std(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        finite = np.isfinite(x)
        cnt = finite.sum(axis=0)
        xs = np.where(finite, x, 0.0)
        mean = np.divide(xs.sum(axis=0), cnt, out=np.zeros(x.shape[1]), where=cnt > 0)
        var = np.divide(
            (np.where(finite, x - mean, 0.0) ** 2).sum(axis=0),
            cnt,
            out=np.zeros(x.shape[1]),
            where=cnt > 0,
        )
        std = np.sqrt(var)
        tiny = std <= 1e-12 * np.maximum(1.0, np.abs(mean))
        return mean, np.where(tiny, 1.0, std)

    zm, zs = mean_std(z)
    um, us = mean_std(u)
    return Stats(zm, zs, um, us)
