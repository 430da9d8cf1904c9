"""Executing force-setpoint chunks in the engine, and a fingerprint of a start state.

A chunk is a sequence of force setpoints ``F_target`` (N), each held for one 20 ms control
step: ``Trial.set_action(F_target)`` without a speed, so the engine's force loop (paper
Eq. 5b) regulates the closing speed toward the setpoint every engine step. This is the
``force`` mode of :mod:`rmi_learn.policies.closed_loop`; the recorded ``v_cmd`` is what that
loop produced and is not executed.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rmi_learn.data.schema import CONTINUOUS_INDEX, FORCE_LIMIT_N, OBS

#: Particle kinds whose arrays enter the state fingerprint.
_KINDS = ("fluid", "solid", "boundary")
#: Config keys left out of the fingerprint: the squeeze force only sets the scripted target,
#: which an external action replaces in every phase, so it cannot change an executed chunk.
_NOT_STATE = ("squeeze_force",)


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
    import rmi_sph

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


def standardise_record(rec: Any, stats: Any) -> tuple[np.ndarray, np.ndarray]:
    """One observation (a ``take_record()`` dict) as a history row of the dataset windows:
    (23,) values, continuous channels standardised with ``stats`` (a dataset ``Stats``),
    invalid values 0, and the (23,) validity mask."""
    y = np.asarray([float(rec[n]) for n in OBS], dtype=np.float64)
    mask = np.isfinite(y)
    ys = y.copy()
    ci = list(CONTINUOUS_INDEX)
    ys[ci] = stats.standardise_z(y[ci])
    ys[~mask] = 0.0
    return ys.astype(np.float32), mask.astype(np.float32)


def state_fingerprint(sim: Any) -> str:
    """SHA-256 of the trial's physical state: every particle array, the rigid bodies, the
    step count, phase and failure, and the config without the squeeze force.

    The raw ``get_state`` bytes carry the config, so two runs of one grid group (same size,
    porosity and holding force, different squeeze forces) differ in them even while their
    trajectories are bit-identical (before the squeeze); under external force commands the
    squeeze force is never used, so such states execute every chunk identically and count
    once."""
    h = hashlib.sha256()
    cfg = {k: v for k, v in dict(sim.config).items() if k not in _NOT_STATE}
    h.update(json.dumps(cfg, sort_keys=True, default=str).encode())
    h.update(f"{sim.step_count}|{sim.phase}|{sim.failure}".encode())
    for kind in _KINDS:
        arrays = sim.particles(kind)
        for name in sorted(arrays):
            a = np.ascontiguousarray(arrays[name])
            h.update(f"{kind}.{name}{a.dtype}{a.shape}".encode())
            h.update(a.tobytes())
    h.update(json.dumps(sim.bodies(), sort_keys=True, default=str).encode())
    return h.hexdigest()


def state_bytes_hash(state: bytes) -> str:
    """SHA-256 of the raw ``get_state`` bytes."""
    return hashlib.sha256(state).hexdigest()


__all__ = [
    "Execution",
    "clip_force",
    "execute_forces",
    "run_forces",
    "standardise_record",
    "state_bytes_hash",
    "state_fingerprint",
]
