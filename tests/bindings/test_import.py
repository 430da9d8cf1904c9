"""Smoke tests of the installed package: native module, version, exceptions, stubs."""

from __future__ import annotations

import importlib.metadata
import os
import pickle
import re
import subprocess
import sys
from pathlib import Path

import pytest

import rmi_sph

ROOT = Path(__file__).resolve().parents[2]


def workspace_version() -> str:
    """The `[workspace.package] version` of the root Cargo.toml (the crates inherit it)."""
    text = (ROOT / "Cargo.toml").read_text(encoding="utf-8")
    section = re.search(r"^\[workspace\.package\]$(.*?)(?=^\[|\Z)", text, re.M | re.S)
    assert section is not None, "root Cargo.toml has no [workspace.package] table"
    match = re.search(r'^version\s*=\s*"([^"]+)"', section.group(1), re.M)
    assert match is not None, "no version in [workspace.package]"
    return match.group(1)


def test_native_module_is_reexported() -> None:
    from rmi_sph import _rmi_sph

    assert rmi_sph.engine_info is _rmi_sph.engine_info
    assert rmi_sph.RmiError is _rmi_sph.RmiError


def test_version_matches_cargo() -> None:
    assert isinstance(rmi_sph.__version__, str)
    assert rmi_sph.__version__ == workspace_version()
    # maturin writes the same version into the distribution metadata.
    assert importlib.metadata.version("rmi") == rmi_sph.__version__


def test_engine_info() -> None:
    info = rmi_sph.engine_info()
    assert info == {
        "version": rmi_sph.__version__,
        "kernel": "cubic spline, H = 4r",
        "float": "f64",
    }
    # A fresh dict each call: callers may mutate it.
    info["float"] = "f32"
    assert rmi_sph.engine_info()["float"] == "f64"


def test_exception_hierarchy() -> None:
    E = rmi_sph
    assert issubclass(E.RmiError, Exception)
    assert not issubclass(E.RmiError, ValueError)
    assert issubclass(E.ConfigError, E.RmiError)
    assert issubclass(E.ConfigError, ValueError)
    assert issubclass(E.SimulationUnstableError, E.RmiError)
    assert issubclass(E.StateError, E.RmiError)
    for cls in (E.RmiError, E.ConfigError, E.SimulationUnstableError, E.StateError):
        assert cls.__module__ == "rmi_sph._rmi_sph"
        assert cls.__doc__


def test_config_error_mapping() -> None:
    with pytest.raises(ValueError, match="solver.dt") as info:
        rmi_sph._raise_error("config")
    err = info.value
    assert type(err) is rmi_sph.ConfigError
    assert (err.field, err.value, err.expected) == (
        "solver.dt",
        "0.5",
        "a time step in (0, 0.01] s",
    )


def test_unstable_error_mapping() -> None:
    with pytest.raises(rmi_sph.SimulationUnstableError, match="step 42") as info:
        rmi_sph._raise_error("unstable")
    err = info.value
    assert err.step == 42
    assert err.time == pytest.approx(0.021)
    assert err.max_velocity == float("inf")
    assert "CFL" in err.reason


def test_state_and_io_error_mapping() -> None:
    with pytest.raises(rmi_sph.StateError, match="particle count"):
        rmi_sph._raise_error("state")
    with pytest.raises(FileNotFoundError, match="snapshot.bin"):
        rmi_sph._raise_error("io")
    with pytest.raises(ValueError, match="unknown error kind") as info:
        rmi_sph._raise_error("nope")
    assert not isinstance(info.value, rmi_sph.RmiError)


def test_errors_pickle() -> None:
    # Errors cross process boundaries in sweeps (multiprocessing pickles them).
    for kind, cls in [
        ("config", rmi_sph.ConfigError),
        ("unstable", rmi_sph.SimulationUnstableError),
        ("state", rmi_sph.StateError),
    ]:
        with pytest.raises(cls) as info:
            rmi_sph._raise_error(kind)
        again = pickle.loads(pickle.dumps(info.value))
        assert type(again) is cls
        assert again.args == info.value.args
        assert vars(again) == vars(info.value)


def test_import_rmi_learn() -> None:
    import rmi_learn

    assert rmi_learn.__doc__
    assert rmi_learn.__version__ == rmi_sph.__version__


def test_stubs_match_native_module() -> None:
    """`mypy.stubtest` compares python/rmi_sph/_rmi_sph.pyi and engine.pyi (its submodule
    `rmi_sph.engine`) with the compiled module."""
    env = dict(os.environ, MYPYPATH=str(ROOT / "python"))
    proc = subprocess.run(
        [sys.executable, "-m", "mypy.stubtest", "rmi_sph._rmi_sph", "rmi_sph.engine"],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
