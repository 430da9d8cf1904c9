"""Test doubles of the engine's trial runner for the sweep tests.

``fake_runner`` and ``fake_make_config`` stand in for ``rmi_sph.run_trial`` and
``rmi_sph.trial_config``: they return the toy ODE trial of ``rmi_learn.data.synthetic`` with the
exact run-file columns, and fail on purpose for some parameters. They are module-level
functions because spawned workers and Ray workers import them by name.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.data.sweep.grid import RunSpec, validate_grid
from rmi_learn.data.synthetic import simulate_toy_run

FAIL_HOLD = 50.0  # the double raises RuntimeError for this holding force


UNSTABLE_SQUEEZE = 390.0  # ... and SimulationUnstableError for this squeeze force


class SimulationUnstableError(RuntimeError):
    """Stands in for rmi_sph.SimulationUnstableError (matched by class name)."""


def fake_make_config(
    size_cm: int,
    porosity: float,
    hold_force: float,
    squeeze_force: float,
    radius: float,
    seed: int,
    **overrides: Any,
) -> dict[str, Any]:
    """Test double of rmi_sph.trial_config."""
    return {
        "size_cm": size_cm,
        "porosity": porosity,
        "hold_force": hold_force,
        "squeeze_force": squeeze_force,
        "radius": radius,
        "seed": seed,
        **overrides,
    }


def fake_runner(config: dict[str, Any], *, num_threads: int) -> dict[str, Any]:
    """Test double of rmi_sph.run_trial: the toy ODE trial; fails on purpose for some
    parameters; sleeps ``config["sleep"]`` s; logs each start to ``config["log"]``."""
    if "log" in config:
        with open(config["log"], "a") as f:
            f.write(
                f"{config['size_cm']} {config['porosity']} {config['hold_force']} "
                f"{config['squeeze_force']} {config['seed']}\n"
            )
    time.sleep(config.get("sleep", 0.0))
    if config["hold_force"] == FAIL_HOLD:
        raise RuntimeError("boom: solver refused")
    if config["squeeze_force"] == UNSTABLE_SQUEEZE:
        raise SimulationUnstableError("velocity blew up at step 17")
    res = simulate_toy_run(
        config["size_cm"],
        config["porosity"],
        config["hold_force"],
        config["squeeze_force"],
        config["seed"],
    )
    res["outcome"]["num_threads"] = num_threads
    res["outcome"]["particles"] = {"fluid": 100 * config["size_cm"], "solid": 7}
    return {"columns": res["columns"], "outcome": res["outcome"]}


def nan_runner(config: dict[str, Any], *, num_threads: int) -> dict[str, Any]:
    """Test double returning a NaN load: the run file must be refused."""
    res = fake_runner(config, num_threads=num_threads)
    res["columns"]["F_L"] = res["columns"]["F_L"].copy()
    res["columns"]["F_L"][3] = np.nan
    return res


def other_engine_make_config(*args: Any, **overrides: Any) -> dict[str, Any]:
    """The same grid point as ``fake_make_config`` builds, on an engine whose default
    permeability changed."""
    return {**fake_make_config(*args, **overrides), "material": {"permeability": 3e-11}}


def grid(**kw: Any) -> dict[str, Any]:
    g = {
        "name": "test",
        "sizes_cm": [8, 10],
        "porosities": [0.5, 0.7],
        "hold_forces_N": [30, FAIL_HOLD, 150],
        "squeeze_forces_N": [150],
        "seeds": [0],
        "radius_m": 0.01,
        "overrides": {},
    }
    g.update(kw)
    return validate_grid(g)


def logged(path: Path) -> list[str]:
    return path.read_text().splitlines() if path.exists() else []


def trial_args(spec: RunSpec) -> dict[str, Any]:
    p = spec.params
    return {
        "size_cm": p["size_cm"],
        "porosity": p["porosity"],
        "hold_force": p["F_hold"],
        "squeeze_force": p["F_squeeze"],
        "radius": spec.radius,
        "seed": p["seed"],
    }
