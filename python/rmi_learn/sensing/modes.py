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


__all__ = [
    "OBSERVATION_MODES",
    "PRIVILEGED_NAMES",
    "SENSOR_NAMES",
    "check_observation_mode",
    "observation_names",
]
