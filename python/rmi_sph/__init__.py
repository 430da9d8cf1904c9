"""rmi_sph: porous SPH engine for robot sponge squeezing (Python binding of the rmi-sph crate).

Everything public comes from the native module ``rmi_sph._rmi_sph``; this package only
re-exports it so that ``import rmi_sph`` is the one import users need. ``rmi_sph.Trial`` is
the grasp-lift-squeeze trial; ``rmi_sph.engine`` holds the engine's own ``Simulation`` (any
scene of water, porous blocks and rigid bodies, e.g. ``engine.dam_break``).
"""

from typing import TYPE_CHECKING, Any

from rmi_sph._rmi_sph import *  # noqa: F403
from rmi_sph._rmi_sph import Trial as Trial
from rmi_sph._rmi_sph import __version__ as __version__

if TYPE_CHECKING:
    # The trial's previous name, deprecated (see `__getattr__`).
    Simulation = Trial


def __getattr__(name: str) -> Any:
    # `rmi_sph.Simulation` was the trial's name until the engine's own simulation was bound
    # (`rmi_sph.engine.Simulation`); it stays an alias of `Trial` for one release.
    if name == "Simulation":
        import warnings

        warnings.warn(
            "rmi_sph.Simulation is deprecated: the grasp-lift-squeeze trial is rmi_sph.Trial "
            "(same class); the engine's own simulation is rmi_sph.engine.Simulation",
            DeprecationWarning,
            stacklevel=2,
        )
        return Trial
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
