"""The feedback laws and open-loop references the benchmark executes.

- :class:`PI`: the incremental PI loop on an estimate of M_L, F(t+1) = F(t) + Kp (e(t) -
  e(t-1)) + Ki e(t) dt, e = M_L_hat - g (kg), dt = 20 ms, F kept inside the benchmark's
  setpoint bounds (no wind-up); starts from the setpoint applied at the start state.
- :class:`Hold`: the setpoint applied at the start state, held.
- :class:`Fixed`: a fixed setpoint sequence (the logged controller's, or a constant).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from rmi_learn.control_bench.feedback.episode import Tick
from rmi_learn.control_bench.feedback.estimators import Estimator
from rmi_learn.data.schema import CONTROL_DT


@dataclass
class PI:
    """Gains ``ki`` N/(kg s) and ``kp`` N/kg toward the goal ``goal_kg`` (kg), within
    [``lo_N``, ``hi_N``] N."""

    estimator: Estimator
    goal_kg: float
    ki: float
    kp: float
    lo_N: float
    hi_N: float
    _ticks: list[Tick] = field(default_factory=list)
    _u: float = 0.0
    _e: float = 0.0

    def start(self, history: list[Tick]) -> None:
        self._ticks = list(history)
        self._u = min(max(history[-1].applied, self.lo_N), self.hi_N)
        self._e = self.estimator(self._ticks) - self.goal_kg

    def act(self, tick: Tick) -> float:
        if tick is not self._ticks[-1]:
            self._ticks.append(tick)
        e = self.estimator(self._ticks) - self.goal_kg
        u = self._u + self.kp * (e - self._e) + self.ki * e * CONTROL_DT
        self._u, self._e = min(max(u, self.lo_N), self.hi_N), e
        return self._u


@dataclass
class Hold:
    """The start state's setpoint, held."""

    _u: float = 0.0

    def start(self, history: list[Tick]) -> None:
        self._u = history[-1].applied

    def act(self, tick: Tick) -> float:
        return self._u


@dataclass
class Fixed:
    """The setpoints ``forces`` (N), one per control step (the last repeated)."""

    forces: Sequence[float]
    _i: int = 0

    def start(self, history: list[Tick]) -> None:
        self._i = 0

    def act(self, tick: Tick) -> float:
        u = float(self.forces[min(self._i, len(self.forces) - 1)])
        self._i += 1
        return u


__all__ = ["PI", "Fixed", "Hold"]
