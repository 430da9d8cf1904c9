"""Type stubs of ``rmi_sph.engine``, a submodule of the native module (checked by
``mypy.stubtest``).

The porous SPH engine without the robot: ``Simulation`` runs any scene of an engine
configuration (``SimConfig``: water blocks, porous blocks, rigid bodies), e.g. a preset's
(``dam_break``, ``sponge``, ``water_column``). Units are SI (m, s, kg, N, Pa). Errors are the
classes of ``rmi_sph`` (``ConfigError``, ``SimulationUnstableError``, ``StateError``).
"""

import os
from typing import Any, Literal, final

import numpy.typing as npt

__all__ = [
    "Simulation",
    "dam_break",
    "sponge",
    "water_column",
    "default_config",
    "validate_config",
]

@final
class Simulation:
    """A simulation of the porous SPH engine: water, porous skeletons and rigid bodies.

    Parameters
    ----------
    config : dict | str | os.PathLike
        An engine configuration: a dict (missing fields take their defaults, see
        ``default_config()``; the presets return one), JSON text, or the path of a JSON file.
    num_threads : int, optional
        Worker threads of this simulation's own pool (default: ``$RMI_NUM_THREADS``, else
        ``$RAYON_NUM_THREADS``, else the core count). Results do not depend on it.

    Raises
    ------
    ConfigError
        A field is unknown, has the wrong type or is out of range (``err.field`` names it).

    Notes
    -----
    Building the scene first soaks the pore water of porous blocks for
    ``config["scene"]["soak_time"]`` (s). Pickling, ``get_state``/``set_state`` and
    ``save``/``load`` continue bit-identically. The object survives ``os.fork``.
    """

    def __new__(
        cls,
        config: dict[str, Any] | str | os.PathLike[str],
        *,
        num_threads: int | None = None,
    ) -> Simulation: ...
    def step(self, n: int = 1) -> int:
        """Advance ``n`` time steps of ``dt`` with the GIL released.

        Ctrl-C is honoured between steps, at least every 50 ms.

        Returns
        -------
        int
            Steps taken.

        Raises
        ------
        SimulationUnstableError
            The step diverged; the state stays at the last good step.
        """
    @property
    def time(self) -> float:
        """Simulated time (s)."""
    @property
    def dt(self) -> float:
        """Time step (s)."""
    @property
    def step_count(self) -> int:
        """Completed time steps."""
    @property
    def num_threads(self) -> int:
        """Worker threads of this simulation's pool."""
    @property
    def config(self) -> dict[str, Any]:
        """The configuration as a dict (every field; rebuilds this scene)."""
    def particles(
        self, kind: Literal["fluid", "porous", "boundary"]
    ) -> dict[str, npt.NDArray[Any]]:
        """Particle data of one kind as numpy arrays (SI units).

        Parameters
        ----------
        kind : {"fluid", "porous", "boundary"}
            ``"fluid"`` (free and pore water): ``positions`` (N, 3) m, ``velocities`` (N, 3)
            m/s, ``mass`` kg, ``density`` kg/m^3, ``pressure`` Pa, ``porosity`` (local, -),
            ``skeleton_cover`` (-), ``retained`` (part in [0, 1] inside a porous block's
            deformed volume), ``id``. ``"porous"`` (skeletons): ``positions``,
            ``velocities``, ``mass``, ``density`` (bulk, dry), ``pressure`` Pa, ``porosity``
            (-), ``saturation`` (-), ``rest_positions`` m, ``id``. ``"boundary"`` (rigid
            bodies): ``positions``, ``velocities``, ``volume`` m^3, ``body`` (index into
            ``bodies()``).

        Raises
        ------
        ValueError
            Another kind; the message lists the accepted ones.
        """
    def bodies(self) -> list[dict[str, Any]]:
        """The rigid bodies: ``name``, ``shape`` ("box" or "container"), ``half_extents`` (m),
        ``position`` (m), ``rotation`` (quaternion w, x, y, z), ``velocity`` (m/s),
        ``kinematic`` (bool), ``force`` (N, exerted by the particles in the last step)."""
    def set_body_velocity(
        self,
        body: int,
        velocity: tuple[float, float, float],
        angular_velocity: tuple[float, float, float] | None = None,
    ) -> None:
        """Set the velocity (m/s) and angular velocity (rad/s) of a kinematic body.

        Parameters
        ----------
        body : int
            Index into ``bodies()``.
        velocity : tuple of 3 floats
            Linear velocity (m/s).
        angular_velocity : tuple of 3 floats, optional
            Angular velocity (rad/s); None for none.

        Raises
        ------
        ConfigError
            The body does not exist or is not kinematic, or a velocity is not finite.
        """
    def stats(self) -> dict[str, Any]:
        """Figures of the last step.

        Returns
        -------
        dict
            ``pressure`` (``iterations``, ``error``: final mean compression per material,
            fluid first), ``cg``, ``pressure_response`` and ``slip_response``
            (``iterations``, ``residual``: final relative residual), ``neighbour_pairs``,
            ``contacts``, ``seconds`` (wall-clock s per phase: ``neighbours``, ``fields``,
            ``implicit``, ``pressure``, ``pressure_response``, ``rest``).
        """
    def pore_water(self, block: int) -> float:
        """Water held in the pores of porous block ``block`` (kg): rest density times current
        pore volume times saturation.

        Raises
        ------
        ConfigError
            The scene has no such porous block.
        """
    def get_state(self) -> bytes:
        """The full state as bytes (for ``set_state`` or ``from_state``)."""
    def set_state(self, state: bytes) -> None:
        """Replace the whole state with one from ``get_state`` of the same config.

        Raises
        ------
        StateError
            ``state`` is not a state, or is a state of another config (the simulation is
            unchanged; ``Simulation.from_state`` makes a simulation of any state).
        """
    @staticmethod
    def from_state(state: bytes, num_threads: int | None = None) -> Simulation:
        """A simulation continuing from ``state`` (bytes of ``get_state``)."""
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the state to ``path`` atomically."""
    @staticmethod
    def load(path: str | os.PathLike[str], num_threads: int | None = None) -> Simulation:
        """A simulation continuing from a state file written by ``save``."""
    def __reduce__(self) -> tuple[Any, ...]: ...

def dam_break(radius_m: float) -> dict[str, Any]:
    """The SPlisHSPlasH dam break as an engine config.

    A closed 4 x 1.5 x 3 m tank (x, y, height; z up) with a cubic water column of about 1 m in
    a corner; explicit viscosity 0.01 m^2/s, dt = 1 ms.

    Parameters
    ----------
    radius_m : float
        Particle radius r (m): 0.0125 gives 39^3 water particles, 0.05 gives 9^3.

    Raises
    ------
    ConfigError
        The radius is out of range.
    """

def sponge(size_m: tuple[float, float, float], porosity: float, radius_m: float) -> dict[str, Any]:
    """A saturated sponge standing on a floor, centred at x = y = 0, as an engine config.

    Parameters
    ----------
    size_m : tuple of 3 floats
        Size (x, y, z = height) in m, each side rounded to whole particle spacings 2r; e.g.
        one of ``rmi_sph.SPONGE_SIZES_M``.
    porosity : float
        Porosity phi of the skeleton (-).
    radius_m : float
        Particle radius r (m).

    Raises
    ------
    ConfigError
        An argument is out of range (``err.field`` names the config field).
    """

def water_column(radius_m: float, width_m: float, height_m: float) -> dict[str, Any]:
    """A water column in a closed tank twice as tall, as an engine config.

    Parameters
    ----------
    radius_m : float
        Particle radius r (m).
    width_m : float
        Width of the column in x and y (m).
    height_m : float
        Height of the column (m).

    Raises
    ------
    ConfigError
        An argument is out of range (``err.field`` names the config field).
    """

def default_config() -> dict[str, Any]:
    """The default engine configuration as a dict (every field, SI units; an empty scene)."""

def validate_config(config: dict[str, Any] | str | os.PathLike[str]) -> dict[str, Any]:
    """Check an engine configuration and return it complete (defaults filled in).

    Raises
    ------
    ConfigError
        The first bad field (``err.field`` names it).
    """
