"""Executing force-setpoint chunks in the engine.

A chunk is a sequence of force setpoints ``F_target`` (N), each held for one 20 ms control
step: ``Trial.set_action(F_target)`` without a speed, so the engine's force loop (paper
Eq. 5b) regulates the closing speed toward the setpoint every engine step. This is the
``force`` mode of the closed-loop experiment (:mod:`rmi_learn.closed_loop`) and the action of
the goal-reaching benchmark (:mod:`rmi_learn.control_bench`); the recorded ``v_cmd`` is what
that loop produced and is not executed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

import rmi_sph
from rmi_learn.data.schema import FORCE_LIMIT_N


@dataclass
class Execution:
    """What executing commands did: ``status`` (``ok``, ``unstable``, ``error``,
    ``invalid_chunk``), retained water ``M_L`` (kg) after the last command (None unless ok),
    the largest grip load ``peak_force_N`` (N, F_meas averaged over each control step),
    the phase and grasp ``failure`` at the end, and, when kept, the record of every control
    step (``Trial.take_record()``: loads averaged over the step, the rest at its end)."""

    status: str = "ok"
    M_L: float | None = None
    peak_force_N: float | None = None
    phase: str | None = None
    failure: str | None = None
    error: str | None = None
    records: list[dict[str, Any]] = field(default_factory=list)


def clip_force(force: float) -> float:
    """A force setpoint clipped to what ``Trial.set_action`` accepts: [0, FORCE_LIMIT_N] N."""
    return float(min(max(force, 0.0), FORCE_LIMIT_N))


def run_forces(
    sim: Any, forces: np.ndarray, substeps: int, keep_records: bool = False
) -> Execution:
    """Apply the setpoints ``forces`` (n,) N from the trial's current state, each for
    ``substeps`` engine steps (one control step). The caller starts the load-averaging
    interval (``take_record``) where the first command starts."""
    out = Execution()
    f = np.asarray(forces, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(f)):
        out.status, out.error = "invalid_chunk", "the chunk holds non-finite setpoints"
        return out
    peak = -np.inf
    rec: dict[str, Any] = {}
    try:
        for value in f.tolist():
            sim.set_action(clip_force(value))
            sim.step(substeps)
            rec = sim.take_record()
            peak = max(peak, float(rec["F_meas"]))
            if keep_records:
                out.records.append(rec)
    except rmi_sph.SimulationUnstableError as exc:
        out.status, out.error = "unstable", f"{type(exc).__name__}: {exc}"
        return out
    except rmi_sph.RmiError as exc:
        out.status, out.error = "error", f"{type(exc).__name__}: {exc}"
        return out
    out.M_L = float(rec["M_L"]) if rec else None
    out.peak_force_N = float(peak) if rec else None
    out.phase = str(sim.phase)
    out.failure = sim.failure
    return out


def execute_forces(
    sim: Any, state: bytes, forces: np.ndarray, substeps: int, keep_records: bool = False
) -> Execution:
    """Restore ``state`` and execute the setpoint chunk ``forces`` (H,) N (see
    :func:`run_forces`). The same state and chunk give bit-identical results."""
    sim.set_state(state)
    sim.take_record()  # the load average starts at the anchor
    return run_forces(sim, forces, substeps, keep_records)


__all__ = ["Execution", "clip_force", "execute_forces", "run_forces"]
