"""The two observation modes and the channels each one shows.

``privileged`` is the paper's interaction state y_t (23 values, ``schema.OBS``), retained
water, saturation and volumes included: what a simulator knows. ``sensors`` is what a real
parallel gripper measures: its width, the two pad loads and their mean, the tactile pads'
contact areas, bilateral-contact flag, shear (the friction force the pads exert) and
stick/slip flags, and the wrist load of a force/torque sensor between wrist and fingers
(``W_x, W_y, W_z``, see ``rmi_robot::observe``). No ``M_L``, ``S``, ``V_pore`` or
``V_sponge``. The task and its score stay on the true ``M_L`` in either mode.
"""

from __future__ import annotations

import numpy as np

from rmi_learn.data.schema import OBS
from rmi_learn.errors import InputError

OBSERVATION_MODES: tuple[str, ...] = ("privileged", "sensors")
PRIVILEGED_NAMES: tuple[str, ...] = OBS
SENSOR_NAMES: tuple[str, ...] = (
    "w",
    "F_meas",
    "F_L",
    "F_R",
    "A_L",
    "A_R",
    "c",
    "F_fric_x",
    "F_fric_y",
    "F_fric_z",
    "r_stick",
    "r_slip",
    "r_mixed",
    "W_x",
    "W_y",
    "W_z",
)


def check_observation_mode(mode: object, field: str = "observation_mode") -> str:
    """``mode`` if it names an observation mode, else :class:`InputError` naming ``field``."""
    if not isinstance(mode, str) or mode not in OBSERVATION_MODES:
        raise InputError(f"{field} must be one of {', '.join(OBSERVATION_MODES)} (got {mode!r})")
    return mode


def observation_names(mode: str) -> tuple[str, ...]:
    """The channels the robot observes in ``mode``, in order."""
    return PRIVILEGED_NAMES if check_observation_mode(mode) == "privileged" else SENSOR_NAMES


#: Channels that cannot be negative: masses, volumes, the width, normal loads, contact
#: areas, the slip speed's magnitude (and the flags).
NON_NEGATIVE: frozenset[str] = frozenset(
    {"M_L", "S", "V_pore", "V_sponge", "w", "F_meas", "F_L", "F_R", "A_L", "A_R", "v_res"}
)
#: Flags and class indicators, within [0, 1].
UNIT_INTERVAL: frozenset[str] = frozenset({"c", "r_none", "r_stick", "r_slip", "r_mixed"})


def observation_bounds(mode: str) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bound of each channel of ``mode`` (float32, -inf / inf where none):
    the physical ones of :data:`NON_NEGATIVE` and :data:`UNIT_INTERVAL` in ``privileged``;
    in ``sensors`` only the flags, which are read without error (a noisy load, area or
    width reads below zero near zero)."""
    names = observation_names(mode)
    exact = mode == "privileged"
    low = [0.0 if n in UNIT_INTERVAL or (exact and n in NON_NEGATIVE) else -np.inf for n in names]
    high = [1.0 if n in UNIT_INTERVAL else np.inf for n in names]
    return np.array(low, dtype=np.float32), np.array(high, dtype=np.float32)


__all__ = [
    "NON_NEGATIVE",
    "OBSERVATION_MODES",
    "UNIT_INTERVAL",
    "observation_bounds",
    "PRIVILEGED_NAMES",
    "SENSOR_NAMES",
    "check_observation_mode",
    "observation_names",
]
