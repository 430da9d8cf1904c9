"""The standardisation that policies and world models are trained in, as tensors: the
training split's mean and standard deviation of the 18 continuous channels and of the force
setpoint, and the check that two runs share it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

#: Index of M_L in the continuous state.
WATER = 0


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


def stats_close(a: Any, b: Any) -> bool:
    """Whether the statistics object ``a`` (``z_mean`` ... attributes, e.g. a dataset's
    ``Stats``) and the statistics dict ``b`` (``Stats.to_json()``) agree to 1e-6."""
    return all(
        np.allclose(np.asarray(getattr(a, k)), np.asarray(b[k]), rtol=1e-6, atol=0.0)
        for k in ("z_mean", "z_std", "u_mean", "u_std")
    )


__all__ = ["WATER", "Standardiser", "stats_close"]
