"""The water goal of the squeeze environment: checked goal options and the reachable default.

A squeeze releases only a small part of the water a sponge holds, so a goal given as a
fraction of the water held at hand-over is easily out of reach. The default goal is therefore
measured, not assumed: from the hand-over state, a constant force setpoint of
``REFERENCE_SQUEEZE_N`` runs the trial to its end, and the most water it releases on the way,
``R`` (kg), is the reference release. The goal is the water retained at hand-over less
``RELEASE_FRACTION`` of ``R``: a strong constant squeeze passes through it, and a controller
has to stop the release there rather than squeeze as hard as it can.
"""

from __future__ import annotations

import math
from typing import Any

import rmi_sph

#: Force setpoint (N) of the reference squeeze: strong, and below the gripper's 400 N limit.
REFERENCE_SQUEEZE_N = 300.0
#: Default part of the reference release the goal asks for.
RELEASE_FRACTION = 0.5


def goal_mass(goal: Any) -> float:
    """A goal retained water mass (kg): finite and not negative."""
    g = float(goal)
    if not (math.isfinite(g) and g >= 0.0):
        raise ValueError(f"goal must be a retained water mass >= 0 kg, got {goal!r}")
    return g


def unit_fraction(name: str, value: Any) -> float:
    """``value`` as a fraction in [0, 1]; a ``ValueError`` naming ``name`` otherwise."""
    f = float(value)
    if not 0.0 <= f <= 1.0:
        raise ValueError(f"{name} must be in [0, 1], got {value!r}")
    return f


def reference_release(
    trial: rmi_sph.Trial, force_n: float = REFERENCE_SQUEEZE_N, substeps: int = 1
) -> float:
    """The most water (kg) a constant force setpoint ``force_n`` (N, tracked by the engine's
    force loop) releases from ``trial``'s current state: its retained water now less the
    least retained water seen every ``substeps`` simulator steps until the trial ends, fails
    or becomes unstable. Advances ``trial`` (pass a copy of the state you keep)."""
    start = float(trial.observation()["M_L"])
    least = start
    trial.set_action(force_n)
    while not trial.finished and trial.time <= trial.time_limit:
        try:
            trial.step(substeps, stop_at_finish=True)
        except rmi_sph.SimulationUnstableError:
            break
        least = min(least, float(trial.observation()["M_L"]))
    return max(0.0, start - least)


def reachable_goal(handover_water: float, release: float, fraction: float) -> float:
    """The default goal (kg): ``handover_water`` (kg) less ``fraction`` of ``release`` (kg)."""
    return max(0.0, handover_water - fraction * release)
