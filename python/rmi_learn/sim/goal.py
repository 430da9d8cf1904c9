"""The water goal of the squeeze environment: checked goal options and the reachable default.

A squeeze releases only a small part of the water a sponge holds, so a goal given as a
fraction of the water held at hand-over is easily out of reach. The default goal is therefore
measured, not assumed: from the hand-over state, a constant force setpoint of
``REFERENCE_SQUEEZE_N`` runs the trial to its end, and the most water it releases on the way,
``R`` (kg), is the reference release. The goal is the water retained at hand-over less
``RELEASE_FRACTION`` of ``R``: a strong constant squeeze passes through it, and a controller
has to stop the release there rather than squeeze as hard as it can.

The checks take real numbers only: a bool, a string, ``None`` or a complex number is a
``TypeError`` naming the option, a value out of range (or too large for a float) a
``ValueError``, so that ``True`` is never taken for 1 kg.
"""

from __future__ import annotations

import math
import numbers
from typing import Any

import rmi_sph

#: Force setpoint (N) of the reference squeeze: strong, and below the gripper's 400 N limit.
REFERENCE_SQUEEZE_N = 300.0
#: Default part of the reference release the goal asks for.
RELEASE_FRACTION = 0.5


def shown(value: Any, width: int = 60) -> str:
    """``repr(value)`` on one line (an array's rows joined) and cut to ``width`` characters,
    for a message that quotes a rejected value."""
    try:
        text = " ".join(repr(value).split())
    except ValueError:  # an integer beyond the digits Python converts to text
        return f"<{type(value).__name__}>"
    return text if len(text) <= width else text[: width - 3] + "..."


def real_number(name: str, value: Any, accepted: str) -> float:
    """``value`` as a float, for the numeric option ``name`` whose ``accepted`` range the
    messages state: a ``TypeError`` for anything but a real number (bools included), a
    ``ValueError`` for an integer too large for a float."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be {accepted}, got {shown(value)} ({type(value).__name__})")
    try:
        return float(value)
    except OverflowError:
        raise ValueError(
            f"{name} must be {accepted}, got an integer too large for a float"
        ) from None


def goal_mass(goal: Any, name: str = "goal") -> float:
    """A goal retained water mass (kg): a real number, finite and not negative; the errors
    name the option ``name``."""
    accepted = "a retained water mass >= 0 kg"
    g = real_number(name, goal, accepted)
    if not (math.isfinite(g) and g >= 0.0):
        raise ValueError(f"{name} must be {accepted}, got {goal!r}")
    return g


def unit_fraction(name: str, value: Any) -> float:
    """``value`` as a fraction in [0, 1]; a ``ValueError`` (``TypeError`` for a value that is
    not a real number) naming ``name`` otherwise."""
    f = real_number(name, value, "in [0, 1]")
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
