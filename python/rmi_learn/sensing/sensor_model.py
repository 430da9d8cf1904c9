"""The sensors' noise and latency: seeded, deterministic, configurable, zero available.

Each observed value is the true value ``latency_ticks`` control steps (20 ms each) earlier,
plus independent Gaussian noise drawn for the current tick. The defaults are the orders of
magnitude of real hardware: a small 6-axis wrist force/torque sensor resolves about
0.05-0.1 N (``wrist_N`` 0.06 N); the pad force of a gripper's finger sensing about 0.5 N,
the same for the tactile pads' shear; a width encoder 0.1 mm; a tactile array's contact
area about one 2 x 2 mm taxel; one tick of latency. ``F_meas`` stays the mean of the two
noisy pad loads, and the contact and stick/slip flags are read without error.

The noise of an episode comes from one generator seeded by ``(seed, *key)`` and drawn tick
by tick in channel order, so :class:`SensorStream` (online, one record at a time) and
:func:`observe_rows` (a whole record at once) give the same bits.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from rmi_learn.errors import InputError
from rmi_learn.sensing.modes import SENSOR_NAMES

#: The longest latency accepted (control steps): half a second.
MAX_LATENCY_TICKS = 25
#: Each noise level's upper bound, far above any real sensor (SI units of the field).
MAX_NOISE = {
    "width_m": 0.01,
    "pad_force_N": 50.0,
    "area_m2": 1e-3,
    "shear_N": 50.0,
    "wrist_N": 10.0,
}
#: Which noise level applies to which channel (channels not named are read exactly).
NOISE_OF = {
    "w": "width_m",
    "F_L": "pad_force_N",
    "F_R": "pad_force_N",
    "A_L": "area_m2",
    "A_R": "area_m2",
    "F_fric_x": "shear_N",
    "F_fric_y": "shear_N",
    "F_fric_z": "shear_N",
    "W_x": "wrist_N",
    "W_y": "wrist_N",
    "W_z": "wrist_N",
}
_NOISY = tuple(i for i, n in enumerate(SENSOR_NAMES) if n in NOISE_OF)
_F = (SENSOR_NAMES.index("F_meas"), SENSOR_NAMES.index("F_L"), SENSOR_NAMES.index("F_R"))


@dataclass(frozen=True)
class SensorModel:
    """Noise standard deviations (SI: m, N, m^2) and latency (control steps) of the
    ``sensors`` observation mode, with the seed of the noise."""

    width_m: float = 1e-4
    pad_force_N: float = 0.5
    area_m2: float = 4e-6
    shear_N: float = 0.5
    wrist_N: float = 0.06
    latency_ticks: int = 1
    seed: int = 0

    def __post_init__(self) -> None:
        for name, hi in MAX_NOISE.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise InputError(f"sensors.{name} must be a number in [0, {hi}] (got {v!r})")
            if not 0.0 <= float(v) <= hi:
                raise InputError(f"sensors.{name} must be in [0, {hi}] (got {v!r})")
        lat = self.latency_ticks
        if isinstance(lat, bool) or not isinstance(lat, int) or not 0 <= lat <= MAX_LATENCY_TICKS:
            raise InputError(
                f"sensors.latency_ticks must be an integer in [0, {MAX_LATENCY_TICKS}] "
                f"(got {lat!r})"
            )
        seed = self.seed
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
            raise InputError(f"sensors.seed must be an integer in [0, 2^63) (got {seed!r})")

    @classmethod
    def noiseless(cls, latency_ticks: int = 0) -> SensorModel:
        """No noise and ``latency_ticks`` of latency."""
        zero: dict[str, Any] = dict.fromkeys(MAX_NOISE, 0.0)
        return cls(**zero, latency_ticks=latency_ticks)

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None) -> SensorModel:
        """A model from a protocol's or a config's ``sensors`` object (missing fields keep
        their defaults); unknown fields are refused by name."""
        if m is None:
            return cls()
        if not isinstance(m, Mapping):
            raise InputError(f"sensors must be an object (got {type(m).__name__})")
        known = {f.name for f in fields(cls)}
        extra = sorted(set(m) - known)
        if extra:
            raise InputError(
                f"sensors has unknown field {extra[0]!r} (known: {', '.join(sorted(known))})"
            )
        return cls(**dict(m))

    def as_dict(self) -> dict[str, Any]:
        """The model's fields, for a table's provenance."""
        return asdict(self)

    def check_history(self, history: int, field: str = "history") -> None:
        """Refuse a latency that leaves no observed row in a history of ``history`` control
        steps."""
        if self.latency_ticks >= history:
            raise InputError(
                f"sensors.latency_ticks = {self.latency_ticks} is not shorter than the {field} "
                f"of {history} control steps (accepted: 0 to {history - 1})"
            )

    def stds(self) -> np.ndarray:
        """Noise standard deviation per channel of ``SENSOR_NAMES`` (0 for exact ones)."""
        return np.array(
            [float(getattr(self, NOISE_OF[n])) if n in NOISE_OF else 0.0 for n in SENSOR_NAMES]
        )

    def generator(self, key: Sequence[int]) -> np.random.Generator:
        """The noise generator of the episode ``key`` (non-negative integers)."""
        return np.random.default_rng([int(self.seed), *(int(k) for k in key)])


def true_row(record: Mapping[str, Any]) -> np.ndarray:
    """The ``SENSOR_NAMES`` values of an engine record (``Trial.take_record``) or of one row
    of a run file, as float64."""
    return np.array([float(record[n]) for n in SENSOR_NAMES], dtype=np.float64)


def _noisy(row: np.ndarray, stds: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = row.copy()
    out[list(_NOISY)] += stds[list(_NOISY)] * rng.standard_normal(len(_NOISY))
    out[_F[0]] = 0.5 * (out[_F[1]] + out[_F[2]])
    return out


class SensorStream:
    """Online sensing of one episode: :meth:`observe` takes each control step's true record
    and returns what the sensors report at that tick."""

    def __init__(self, model: SensorModel, key: Sequence[int]) -> None:
        self.model = model
        self._rng = model.generator(key)
        self._stds = model.stds()
        self._buf: deque[np.ndarray] = deque(maxlen=model.latency_ticks + 1)

    def observe(self, record: Mapping[str, Any] | np.ndarray) -> np.ndarray:
        """The observed ``SENSOR_NAMES`` row (C,) after this tick's true record."""
        row = record if isinstance(record, np.ndarray) else true_row(record)
        self._buf.append(np.asarray(row, dtype=np.float64))
        return _noisy(self._buf[0], self._stds, self._rng)


def observe_rows(rows: np.ndarray, model: SensorModel, key: Sequence[int]) -> np.ndarray:
    """What the sensors report for a whole episode of true ``SENSOR_NAMES`` rows (T, C): row
    t is row ``max(t - latency, 0)`` plus tick t's noise; the same bits as a
    :class:`SensorStream` fed the rows in order."""
    stream = SensorStream(model, key)
    return np.stack([stream.observe(r) for r in np.asarray(rows, dtype=np.float64)])


__all__ = [
    "MAX_LATENCY_TICKS",
    "NOISE_OF",
    "SensorModel",
    "SensorStream",
    "observe_rows",
    "true_row",
]
