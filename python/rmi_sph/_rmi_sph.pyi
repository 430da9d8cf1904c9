"""Type stubs of the native module ``rmi_sph._rmi_sph`` (checked by ``mypy.stubtest``)."""

import os
from collections.abc import Sequence
from typing import Any, Final, Literal, final

import numpy as np
import numpy.typing as npt

from rmi_sph import engine as engine

# pyo3 lists everything added to the module in __all__, so `from ._rmi_sph import *` takes it all.
__all__ = [
    "__version__",
    "OBSERVATION_NAMES",
    "EXTRA_NAMES",
    "ACTION_NAMES",
    "FORCE_LIMIT_N",
    "SEED_MAX",
    "SPONGE_SIZES_M",
    "engine_info",
    "_raise_error",
    "run_trial",
    "run_squeeze_group",
    "trial_config",
    "default_config",
    "validate_config",
    "Trial",
    "engine",
    "GruForecaster",
    "RmiError",
    "ConfigError",
    "SimulationUnstableError",
    "StateError",
]

__version__: str

#: The 23 values of y_t in the paper's order (same as ``rmi_learn.data.schema.OBS``).
OBSERVATION_NAMES: Final[tuple[str, ...]]
#: Recorded extras (same as ``rmi_learn.data.schema.EXTRAS``).
EXTRA_NAMES: Final[tuple[str, ...]]
#: Action channels (same as ``rmi_learn.data.schema.ACTIONS``).
ACTION_NAMES: Final[tuple[str, ...]]
#: Hard force limit of the gripper (N): targets are clipped to it, loads above it open.
FORCE_LIMIT_N: Final[float]
#: Largest seed a config takes (2^63 - 1): every seed is an integer in [0, SEED_MAX].
SEED_MAX: Final[int]
#: The paper's three sponges as (x, y, z) sizes in m, small to large.
SPONGE_SIZES_M: Final[tuple[tuple[float, float, float], ...]]

def engine_info() -> dict[str, str]:
    """Build facts of the engine: ``version``, ``kernel`` and ``float``."""

def _raise_error(kind: str) -> None:
    """Raise the exception a core error of ``kind`` maps to (for tests)."""

def run_trial(
    config: dict[str, Any] | str | os.PathLike[str],
    *,
    num_threads: int | None = None,
    record_every: int | None = None,
) -> dict[str, Any]:
    """Run the scripted trial to its end (GIL released): ``{"columns", "outcome"}``."""

def run_squeeze_group(
    config: dict[str, Any] | str | os.PathLike[str],
    squeeze_forces: Sequence[float],
    *,
    num_threads: int | None = None,
    record_every: int | None = None,
) -> list[dict[str, Any]]:
    """Run the trial once per squeeze force from one shared prefix: ``run_trial``'s results."""

def trial_config(
    size_cm: float,
    porosity: float,
    hold_force: float,
    squeeze_force: float,
    radius: float = 0.005,
    seed: int = 0,
    **overrides: Any,
) -> dict[str, Any]:
    """A trial config (dict) of one of the paper's sponges (8, 10 or 12 cm)."""

def default_config() -> dict[str, Any]:
    """The default trial configuration as a dict."""

def validate_config(config: dict[str, Any] | str | os.PathLike[str]) -> dict[str, Any]:
    """Check a configuration; return it complete as a dict."""

@final
class Trial:
    """A grasp-lift-squeeze trial stepped from Python (called ``Simulation`` before; that name
    is a deprecated alias for one release)."""

    def __new__(
        cls,
        config: dict[str, Any] | str | os.PathLike[str],
        *,
        num_threads: int | None = None,
        record: bool = False,
    ) -> Trial: ...
    def step(self, n: int = 1, *, stop_at_finish: bool = False) -> int:
        """Advance ``n`` simulator steps (GIL released); return the steps taken."""
    @property
    def time(self) -> float:
        """Simulated time (s)."""
    @property
    def dt(self) -> float:
        """Time step (s)."""
    @property
    def step_count(self) -> int:
        """Completed simulator steps."""
    @property
    def num_threads(self) -> int:
        """Worker threads of this trial's pool."""
    @property
    def time_limit(self) -> float:
        """Simulated time after which ``run_trial`` gives up (s)."""
    @property
    def phase(self) -> str:
        """Controller phase name."""
    @property
    def finished(self) -> bool:
        """Whether the trial is over."""
    @property
    def failure(self) -> str | None:
        """Why the trial ended early, or None."""
    @property
    def config(self) -> dict[str, Any]:
        """The configuration as a dict."""
    @property
    def action(self) -> tuple[float, float | None] | None:
        """The external action in force, or None."""
    def observation(self) -> dict[str, Any]:
        """Latest observation: y_t by name plus extras."""
    def observation_vector(self) -> npt.NDArray[np.float64]:
        """The 23 values of y_t, shape (23,)."""
    def take_record(self) -> dict[str, Any]:
        """Observation with pad loads averaged since the previous call."""
    def records(self, *, clear: bool = False) -> dict[str, npt.NDArray[Any]]:
        """Rows recorded so far (``record=True``) as run-file columns."""
    def particles(self, kind: Literal["fluid", "solid", "boundary"]) -> dict[str, npt.NDArray[Any]]:
        """Particle data of one kind as numpy arrays."""
    def bodies(self) -> list[dict[str, Any]]:
        """Rigid bodies (floor, pads) with shape and pose."""
    def set_action(self, force_target: float, velocity_command: float | None = None) -> None:
        """Drive the pads with u_t = [F_target, v_cmd]."""
    def clear_action(self) -> None:
        """Return control to the scripted targets."""
    def outcome(self) -> dict[str, Any]:
        """Outcome so far."""
    def get_state(self) -> bytes:
        """The full state as bytes."""
    def set_state(self, state: bytes) -> None:
        """Replace the whole state with one from ``get_state`` of a trial of the same config.

        Raises StateError (the trial unchanged) for bytes that are not a state or a state
        of another config; ``Trial.from_state`` makes a trial of any state."""
    @staticmethod
    def from_state(state: bytes, num_threads: int | None = None) -> Trial:
        """A trial continuing from ``state``."""
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the state to ``path`` atomically."""
    @staticmethod
    def load(path: str | os.PathLike[str], num_threads: int | None = None) -> Trial:
        """A trial continuing from a state file."""
    def __reduce__(self) -> tuple[Any, ...]: ...

@final
class GruForecaster:
    """Free rollout of a trained AC-GRU-WM or State-GRU-WM in one native call (the
    ``rmi-wm`` crate); ``rmi_learn.world_models.gru`` uses it for inference on CPU."""

    def __new__(
        cls,
        state: dict[str, npt.NDArray[np.float32]],
        keep: npt.NDArray[np.float32],
        assemble: list[int],
        continuous: list[int],
    ) -> GruForecaster: ...
    @staticmethod
    def accelerated() -> bool:
        """Whether this CPU runs the rollout's AVX2 + FMA copy (else it is slow)."""
    @property
    def action_conditioned(self) -> bool:
        """Whether the model reads the commands (AC-GRU-WM)."""
    def forecast(
        self,
        hist: npt.NDArray[np.float32],
        hist_mask: npt.NDArray[np.float32],
        actions: npt.NDArray[np.float32],
        *,
        num_threads: int = 1,
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """``z`` (n, H, 18), ``contact_logit`` (n, H), ``friction_logit`` (n, H, 4) for ``n``
        chunks against ``b`` histories; the same bits for any ``num_threads``."""

class RmiError(Exception):
    """Base class of every error raised by the rmi engine."""

class ConfigError(RmiError, ValueError):
    """A configuration value is outside its accepted range."""

    field: str
    value: str
    expected: str

class SimulationUnstableError(RmiError):
    """The simulation diverged; the state is left at the last good step."""

    step: int
    time: float
    max_velocity: float
    reason: str

class StateError(RmiError):
    """A snapshot or state dictionary does not fit this simulation."""
