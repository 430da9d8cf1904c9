"""rmi_sph: porous SPH engine for robot sponge squeezing (Python binding of the rmi-sph crate).

Everything public comes from the native module ``rmi_sph._rmi_sph``; this package only
re-exports it so that ``import rmi_sph`` is the one import users need.
"""

from rmi_sph._rmi_sph import *  # noqa: F403
from rmi_sph._rmi_sph import __version__ as __version__
