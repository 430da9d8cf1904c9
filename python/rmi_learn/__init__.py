"""rmi_learn: the learning and data half of rmi.

Runs parameter sweeps of the ``rmi_sph`` engine, stores each run as Parquet, builds training
windows from them and trains and evaluates squeezing policies and models. torch and
safetensors are optional (the ``learn`` extra): only the world models, the policies and the
commands that train or run them import them, when they run.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("rmi")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
