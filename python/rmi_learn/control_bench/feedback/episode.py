"""One executed episode: a controller closes the loop tick by tick in the engine.

Every 20 ms control step the controller reads what its observation mode shows (the engine's
record, or the :class:`~rmi_learn.sensing.SensorStream` of it), sets a force setpoint
``F_target`` (N), and the engine's force loop tracks it for ``substeps`` engine steps. After
the ``horizon`` control steps of the task the episode may continue with the pads returned to
``F_hold`` for ``settle_ticks`` (the ``settle`` variant). The score uses the true retained
water ``M_L`` whatever the controller saw.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

import rmi_sph
from rmi_learn.sensing import SensorModel, SensorStream
from rmi_learn.sim.execute import clip_force


@dataclass
class Tick:
    """What a controller sees after a control step: the engine's ``record`` (privileged),
    the sensors' row ``observed`` (``SENSOR_NAMES`` order; None in privileged mode) and the
    setpoint ``applied`` in that step (N)."""

    record: dict[str, Any]
    observed: np.ndarray | None
    applied: float


class Controller(Protocol):
    """A feedback law: ``start`` with the history before the start state, then one setpoint
    (N) per control step."""

    def start(self, history: list[Tick]) -> None: ...

    def act(self, tick: Tick) -> float: ...


@dataclass
class Episode:
    """The outcome: ``status`` (``ok``, ``unstable``, ``error``), the true ``M_L`` (kg) at the
    end of the task's horizon and after the settle, the setpoints applied (N), the peak
    grip load (N) and, when asked for, the ticks the controller saw up to the end of the
    horizon (the history included)."""

    status: str = "ok"
    M_L_reach: float | None = None
    M_L_settle: float | None = None
    forces: list[float] = field(default_factory=list)
    peak_force_N: float | None = None
    error: str | None = None
    seen: list[Tick] = field(default_factory=list)


@dataclass
class Plant:
    """The engine a controller acts on: the trial, its control step in engine steps, the
    setpoint bounds (N) and the grip held during the settle (N)."""

    sim: Any
    substeps: int
    lo_N: float
    hi_N: float
    hold_N: float


def _observe(stream: SensorStream | None, rec: dict[str, Any]) -> np.ndarray | None:
    return None if stream is None else stream.observe(rec)


def run_episode(
    plant: Plant,
    state: bytes,
    history: list[dict[str, Any]],
    controller: Controller,
    horizon: int,
    settle_ticks: int,
    sensors: SensorModel | None,
    key: tuple[int, ...],
    keep_seen: bool = False,
) -> Episode:
    """Restore ``state``, hand the controller the observed ``history`` (the true records of
    the control steps up to the state, the last one at the state), run ``horizon`` control
    steps of its setpoints clipped to the plant's bounds, then ``settle_ticks`` at the
    holding force. ``sensors`` None is the privileged mode; the noise of ``key`` is the same
    for every controller of one start state and goal. ``keep_seen`` keeps the ticks up to
    the end of the horizon in ``Episode.seen``."""
    stream = None if sensors is None else SensorStream(sensors, key)
    past = [Tick(r, _observe(stream, r), float(r["F_target"])) for r in history]
    sim = plant.sim
    sim.set_state(state)
    sim.take_record()
    out = Episode()
    controller.start(past)
    seen = list(past)
    tick = past[-1]
    peak = -np.inf
    try:
        for i in range(horizon + settle_ticks):
            if i < horizon:
                u = float(np.clip(controller.act(tick), plant.lo_N, plant.hi_N))
            else:
                u = plant.hold_N
            sim.set_action(clip_force(u))
            sim.step(plant.substeps)
            rec = sim.take_record()
            peak = max(peak, float(rec["F_meas"]))
            out.forces.append(u)
            tick = Tick(rec, _observe(stream, rec), u)
            if keep_seen and i < horizon:
                seen.append(tick)
            if i == horizon - 1:
                out.M_L_reach = float(rec["M_L"])
        out.M_L_settle = float(tick.record["M_L"]) if settle_ticks else None
    except rmi_sph.SimulationUnstableError as exc:
        out.status, out.error = "unstable", f"{type(exc).__name__}: {exc}"
    except rmi_sph.RmiError as exc:
        out.status, out.error = "error", f"{type(exc).__name__}: {exc}"
    out.peak_force_N = float(peak) if out.forces else None
    if out.status != "ok":
        out.M_L_reach = out.M_L_settle = None
    elif keep_seen:
        out.seen = seen
    return out


__all__ = ["Controller", "Episode", "Plant", "Tick", "run_episode"]
