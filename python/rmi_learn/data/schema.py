"""Names, order and units of the recorded channels: the contract between the engine, the
stored runs and the learning code.

The channel names and their order are the engine's (``rmi_sph.OBSERVATION_NAMES``,
``EXTRA_NAMES``, ``ACTION_NAMES``), as are the gripper's force limit, the paper's sponge
sizes and the range of seeds; this module re-exports them and derives the groups the
learning code uses. The meaning and unit of every channel, the run-file layout and the
dataset API are described in ``docs/data-contract.md``.

The observation ``y_t`` has 23 values in the paper's order (Eq. 7). Units are SI: kg, m, m^3,
N, m^2, m/s. Reports convert water to grams at the end, never in stored data.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import rmi_sph

#: The 23 observation values, in the paper's order (Eq. 7).
OBS: tuple[str, ...] = tuple(rmi_sph.OBSERVATION_NAMES)

#: Index of the contact indicator and of the friction one-hot block in ``OBS``.
CONTACT_INDEX = OBS.index("c")
FRICTION_SLICE = slice(OBS.index("r_none"), OBS.index("r_mixed") + 1)
FRICTION_CLASSES: tuple[str, ...] = ("none", "stick", "slip", "mixed")

#: The 18 continuous entries z_t of y_t (everything except c and the friction one-hot).
CONTINUOUS: tuple[str, ...] = tuple(
    n for i, n in enumerate(OBS) if i != CONTACT_INDEX and not n.startswith("r_")
)
CONTINUOUS_INDEX: tuple[int, ...] = tuple(OBS.index(n) for n in CONTINUOUS)

#: The command recorded each step, u_t = [F_target, v_cmd] (N, m/s; positive v_cmd closes
#: the gripper): the run files' action columns.
ACTIONS: tuple[str, ...] = tuple(rmi_sph.ACTION_NAMES)

#: The action the world models are conditioned on and the policies output: the force
#: setpoint F_target (N), executed by the engine's force loop (``Trial.set_action(F)`` with
#: no speed). The recorded closing speed v_cmd is that loop's output,
#: ``clip(k_F (F_target - F_meas))``, a consequence of the setpoint and the measured load
#: rather than a second command: a chunk of both could ask for a speed the loop would not
#: produce, and only its setpoints can be executed from a new state.
CONTROL_ACTIONS: tuple[str, ...] = ("F_target",)
#: Columns of ``CONTROL_ACTIONS`` within the recorded ``ACTIONS``.
CONTROL_ACTION_INDEX: tuple[int, ...] = tuple(ACTIONS.index(a) for a in CONTROL_ACTIONS)

#: Recorded outside y_t, for analysis only (never model inputs): time (s), phase, the
#: skeleton's centre-of-mass velocity (m/s), the lift gate, expelled water (kg), lift height (m).
EXTRAS: tuple[str, ...] = tuple(rmi_sph.EXTRA_NAMES)

#: The wrist load (N): the force of the sponge and what it carries on the gripper, as a
#: force/torque sensor between wrist and fingers reads it; kept in a dataset's frames for
#: the ``sensors`` observation mode, never part of y_t.
WRIST: tuple[str, ...] = ("W_x", "W_y", "W_z")

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


#: Largest seed anything takes (2^63 - 1, the engine's ``SEED_MAX``): run files and the
#: sweep index store seeds as Int64, and the engine refuses a config seed above it.
SEED_MAX: int = int(rmi_sph.SEED_MAX)

#: The accepted seeds, in the engine's words.
SEED_RANGE = f"an integer in [0, {SEED_MAX}]"


def checked_seed(value: Any, name: str = "seed") -> int:
    """``value`` as a seed (an integer, numpy's included, not a bool, in [0, SEED_MAX]);
    a one-line ``ValueError`` naming ``name`` and the range otherwise."""
    try:
        seed = None if isinstance(value, bool) else operator.index(value)
    except TypeError:
        seed = None
    if seed is None or not 0 <= seed <= SEED_MAX:
        raise ValueError(f"{name} must be {SEED_RANGE}, got {value!r:.80}")
    return seed


#: The gripper's force limit (N): commands are clipped to [0, FORCE_LIMIT_N].
FORCE_LIMIT_N: float = float(rmi_sph.FORCE_LIMIT_N)


def size_cm(size_m: Sequence[float]) -> int:
    """A sponge's size label (cm): its x edge ``size_m[0]`` (m) in whole centimetres."""
    return int(round(float(size_m[0]) * 100))


#: The paper's sponge sizes (cm) in the engine's order: 8, 10 and 12 cm.
SPONGE_SIZES_CM: tuple[int, ...] = tuple(size_cm(s) for s in rmi_sph.SPONGE_SIZES_M)
