"""Names, order and units of the recorded channels: the contract between the engine, the
stored runs and the learning code.

The full data and API contract (run files, dataset API, rules for contributors) is
``python/rmi_learn/CONTRACT.md``: read it before writing learning or data code.

The observation ``y_t`` has 23 values in the paper's order (Eq. 7). Units are SI: kg, m, m^3,
N, m^2, m/s. Reports convert water to grams at the end, never in stored data.
"""

from __future__ import annotations

#: The 23 observation values, in the paper's order (Eq. 7).
OBS: tuple[str, ...] = (
    "M_L",  # retained liquid mass (kg)
    "S",  # mean saturation of the skeleton (-)
    "V_pore",  # current pore volume (m^3)
    "V_sponge",  # current sponge volume (m^3)
    "w",  # gripper width, between the pad faces (m)
    "F_meas",  # realised grip load, mean of F_L and F_R (N)
    "F_L",  # normal load on the left pad (N)
    "F_R",  # normal load on the right pad (N)
    "alpha_F",  # load imbalance |F_L - F_R| / (F_L + F_R + eps) (-)
    "A_L",  # contact area on the left pad (m^2)
    "A_R",  # contact area on the right pad (m^2)
    "c",  # valid bilateral contact (0/1)
    "v_tan_x",  # mean tangential slip velocity before friction (m/s)
    "v_tan_y",
    "v_tan_z",
    "F_fric_x",  # total friction force applied to the sponge by the pads (N)
    "F_fric_y",
    "F_fric_z",
    "v_res",  # residual slip after friction (m/s); NaN without contact
    "r_none",  # friction regime, one-hot: none / stick / slip / mixed
    "r_stick",
    "r_slip",
    "r_mixed",
)

#: Index of the contact indicator and of the friction one-hot block in ``OBS``.
CONTACT_INDEX = OBS.index("c")
FRICTION_SLICE = slice(OBS.index("r_none"), OBS.index("r_mixed") + 1)
FRICTION_CLASSES: tuple[str, ...] = ("none", "stick", "slip", "mixed")

#: The 18 continuous entries z_t of y_t (everything except c and the friction one-hot).
CONTINUOUS: tuple[str, ...] = tuple(
    n for i, n in enumerate(OBS) if i != CONTACT_INDEX and not n.startswith("r_")
)
CONTINUOUS_INDEX: tuple[int, ...] = tuple(OBS.index(n) for n in CONTINUOUS)

#: The action u_t = [F_target, v_cmd] (N, m/s; positive v_cmd closes the gripper).
ACTIONS: tuple[str, ...] = ("F_target", "v_cmd")

#: Recorded outside y_t, for analysis only (never model inputs).
EXTRAS: tuple[str, ...] = (
    "time",  # simulated time (s)
    "phase",  # controller phase name (see PHASES)
    "v_com_x",  # skeleton centre-of-mass velocity (m/s)
    "v_com_y",
    "v_com_z",
    "gate_open",  # lift gate state (bool)
    "M_expelled",  # liquid mass outside the skeleton's support (kg)
    "lift_height",  # plate displacement along the lift axis since the lift began (m)
)

#: Controller phases in the order a trial visits them.
PHASES: tuple[str, ...] = (
    "settle",
    "close",
    "ramp",
    "hold",
    "lift",
    "waiting",
    "squeeze",
    "done",
)

#: Phases learning windows are drawn from (Sec. V); "waiting" duplicates the hold.
LEARNING_PHASES: tuple[str, ...] = ("close", "ramp", "hold", "lift", "squeeze")

#: Channels with physical zeros when there is no contact; only v_res is undefined then.
MASKED_WITHOUT_CONTACT: tuple[str, ...] = ("v_res",)

#: Resampling grid of the learning data (s), history and horizon lengths (Sec. V).
CONTROL_DT = 0.02
HISTORY = 16
HORIZON = 64
