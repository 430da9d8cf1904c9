"""The retained water estimated from the wrist load: what a scale in the wrist tells.

Carried in the air, the wrist load's vertical component is minus the weight of the sponge
with all the water it carries. Minus the dry sponge's mass (the robot can weigh it before
the task), that is the water in the pores plus the expelled water that has not dripped off
yet; the estimate's ``offset`` (kg) stands for the latter and is fitted on validation
states only. On the floor, before the lift, the floor carries part of the weight and the
estimate means nothing.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Magnitude of the scenes' gravity (m/s^2): the engine's default, (0, 0, -9.81).
STANDARD_GRAVITY = 9.81


def dry_mass(trial: Any) -> float:
    """The dry sponge's mass (kg): the skeleton particles' masses of ``trial``."""
    return float(np.sum(trial.particles("solid")["mass"], dtype=np.float64))


def weight_estimate(
    w_z: float | np.ndarray, m_dry: float, offset: float = 0.0, g: float = STANDARD_GRAVITY
) -> float | np.ndarray:
    """Retained water estimated from the vertical wrist load ``w_z`` (N): -w_z / g minus the
    dry mass ``m_dry`` and the carried-water ``offset`` (kg)."""
    return -w_z / g - m_dry - offset


__all__ = ["STANDARD_GRAVITY", "dry_mass", "weight_estimate"]
