"""Type stubs of the native module ``rmi_sph._rmi_sph`` (checked by ``mypy.stubtest``)."""

# pyo3 lists everything added to the module in __all__, so `from ._rmi_sph import *` takes it all.
__all__ = [
    "__version__",
    "engine_info",
    "_raise_error",
    "RmiError",
    "ConfigError",
    "SimulationUnstableError",
    "StateError",
]

__version__: str

def engine_info() -> dict[str, str]:
    """Build facts of the engine: ``version``, ``kernel`` and ``float``."""

def _raise_error(kind: str) -> None:
    """Raise the exception a core error of ``kind`` maps to (for tests)."""

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
