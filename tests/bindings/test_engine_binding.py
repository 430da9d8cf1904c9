"""The engine's own simulation from Python: `rmi_sph.engine` (no robot layer).

Scenes are coarse: the dam break at r = 4 cm (1,728 water particles) and the 8 cm sponge at
r = 1 cm (144 skeleton particles and their pore water) step in well under a second each.
"""

from __future__ import annotations

import json
import os
import pickle
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import rmi_sph
from binding_util import assert_interruptible, in_forked_child, same
from rmi_sph import engine

#: Particle radius of the test dam break (m).
DAM_RADIUS = 0.04


@pytest.fixture(scope="module")
def dam() -> dict[str, Any]:
    return engine.dam_break(DAM_RADIUS)


@pytest.fixture(scope="module")
def sponge() -> dict[str, Any]:
    return engine.sponge(rmi_sph.SPONGE_SIZES_M[0], 0.6, 0.01)


def test_module_layout() -> None:
    import rmi_sph.engine as imported

    assert imported is engine is rmi_sph.engine
    assert engine.__name__ == "rmi_sph.engine"
    assert engine.Simulation.__module__ == "rmi_sph.engine"
    assert engine.Simulation.__module__ != rmi_sph.Trial.__module__
    assert engine.__doc__


def test_dam_break_falls_and_keeps_its_particles(dam: dict[str, Any]) -> None:
    sim = engine.Simulation(dam, num_threads=2)
    assert sim.config == dam
    assert (sim.time, sim.step_count, sim.dt, sim.num_threads) == (0.0, 0, 1e-3, 2)
    fluid = sim.particles("fluid")
    n = fluid["positions"].shape[0]
    assert n == 12**3
    assert sim.particles("porous")["positions"].shape == (0, 3)
    z0 = fluid["positions"][:, 2].mean()
    # Fields are there before the first step: water at rest density in the column's interior.
    assert np.all(np.isfinite(fluid["density"])) and np.median(fluid["density"]) == pytest.approx(
        1000.0, rel=0.05
    )
    assert sim.step() == 1 and sim.step(79) == 79
    assert sim.step_count == 80 and sim.time == pytest.approx(0.08)
    assert sim.step(0) == 0
    fluid = sim.particles("fluid")
    assert fluid["positions"].shape == (n, 3) and fluid["velocities"].shape == (n, 3)
    for key in ("mass", "density", "pressure", "porosity", "retained", "id"):
        assert fluid[key].shape == (n,), key
    assert sorted(fluid["id"]) == list(range(n))
    assert np.all(np.isfinite(fluid["positions"]))
    # The column slumps under gravity: its mean height drops, about 1/2 g t^2 at first.
    z1 = fluid["positions"][:, 2].mean()
    assert z1 < z0 - 0.005
    assert fluid["velocities"][:, 2].mean() < 0
    assert np.all(fluid["pressure"] >= 0)  # the pressure solve only resists compression
    bnd = sim.particles("boundary")
    assert bnd["positions"].shape[0] == bnd["volume"].shape[0] == bnd["body"].shape[0] > 0
    (tank,) = sim.bodies()
    assert tank["name"] == "tank" and tank["shape"] == "container" and not tank["kinematic"]
    stats = sim.stats()
    assert stats["pressure"]["iterations"] >= 2 and len(stats["pressure"]["error"]) == 1
    assert stats["neighbour_pairs"] > 0
    assert set(stats["seconds"]) == {
        "neighbours", "fields", "implicit", "pressure", "pressure_response", "rest",
    }  # fmt: skip
    assert set(stats["cg"]) == {"iterations", "residual"}
    assert "Simulation(" in repr(sim) and "fluid=1728" in repr(sim)


def test_threads_give_bit_identical_positions(dam: dict[str, Any]) -> None:
    sims = [engine.Simulation(dam, num_threads=k) for k in (1, 2)]
    for s in sims:
        s.step(60)  # past a fluid re-sort (every 25 steps)
    a, b = (s.particles("fluid") for s in sims)
    for key in a:
        assert same(a[key], b[key]), key


def _continue(sim: engine.Simulation, n: int = 15) -> tuple[np.ndarray, ...]:
    sim.step(n)
    return tuple(sim.particles(k)["positions"] for k in ("fluid", "porous"))


def test_state_round_trip_continues_identically(sponge: dict[str, Any], tmp_path: Path) -> None:
    sim = engine.Simulation(sponge, num_threads=1)
    sim.step(20)
    state = sim.get_state()
    assert isinstance(state, bytes)
    pickled = pickle.loads(pickle.dumps(sim))
    assert type(pickled) is engine.Simulation
    from_state = engine.Simulation.from_state(state, num_threads=2)
    sim.save(tmp_path / "s.bin")
    loaded = engine.Simulation.load(tmp_path / "s.bin", num_threads=1)
    with pytest.raises(rmi_sph.StateError, match="differs"):
        engine.Simulation(engine.dam_break(0.05), num_threads=1).set_state(state)
    other = engine.Simulation(sponge, num_threads=1)
    other.set_state(state)
    assert other.config == sponge and other.time == sim.time
    assert other.step_count == sim.step_count == 20
    ref = _continue(sim)
    for s in (pickled, from_state, loaded, other):
        got = _continue(s)
        assert all(same(x, y) for x, y in zip(got, ref, strict=True))
    with pytest.raises(rmi_sph.StateError):
        sim.set_state(b"not a state")
    with pytest.raises(rmi_sph.StateError):
        sim.set_state(state[:100])
    with pytest.raises(rmi_sph.StateError):
        sim.set_state("text")  # type: ignore[arg-type]
    with pytest.raises(FileNotFoundError):
        engine.Simulation.load(tmp_path / "missing.bin")
    # A failed restore leaves the simulation as it was.
    assert sim.step_count == 35


def test_sponge_preset_holds_pore_water(sponge: dict[str, Any]) -> None:
    (block,) = sponge["scene"]["porous_blocks"]
    assert block["saturated"] and block["material"]["porosity"] == 0.6
    sim = engine.Simulation(sponge, num_threads=2)
    porous = sim.particles("porous")
    assert porous["positions"].shape == (4 * 4 * 9, 3)
    assert {"saturation", "rest_positions", "porosity"} <= set(porous)
    # Saturated at the start: about rho_f phi V of the 8 x 8 x 18 cm block (the lattice's
    # pore water is a little thinner near the faces, so saturation starts just under 1).
    initial = sim.pore_water(0)
    assert initial == pytest.approx(1000.0 * 0.6 * 0.08 * 0.08 * 0.18, rel=0.05)
    sim.step(10)
    water = sim.pore_water(0)
    assert np.isfinite(water) and 0 < water <= initial * 1.05
    assert np.all((porous["saturation"] >= 0) & (porous["saturation"] <= 1))
    for bad in (1, -1):
        with pytest.raises(rmi_sph.ConfigError) as info:
            sim.pore_water(bad)
        assert info.value.field == "block"


def test_bad_config_names_the_field(dam: dict[str, Any], tmp_path: Path) -> None:
    with pytest.raises(rmi_sph.ConfigError) as info:
        engine.Simulation({**dam, "dt": 0.5})
    assert info.value.field == "dt" and "0.5" in str(info.value)
    with pytest.raises(rmi_sph.ConfigError) as info:
        engine.validate_config({"fluid": {"density": -1.0}})
    assert info.value.field == "fluid.density"
    assert isinstance(info.value, ValueError)
    with pytest.raises(rmi_sph.ConfigError) as info:
        engine.Simulation({"fluid": {"densty": 1000.0}})
    assert info.value.field == "fluid.densty"
    with pytest.raises(rmi_sph.ConfigError) as info:
        engine.validate_config({"dt": float("nan")})
    assert info.value.field == "dt"
    cases: list[tuple[Callable[[], object], str]] = [
        (lambda: engine.dam_break(-0.01), "particle_radius"),
        (
            lambda: engine.sponge((0.08, 0.08, 0.18), 1.5, 0.01),
            "scene.porous_blocks[0].material.porosity",
        ),
        (lambda: engine.Simulation(dam, num_threads=-1), "num_threads"),
        (lambda: engine.Simulation(dam, num_threads=0), "num_threads"),
        (lambda: engine.Simulation.from_state(b"", num_threads=-2), "num_threads"),
    ]
    for bad, field in cases:
        with pytest.raises(rmi_sph.ConfigError) as info:
            bad()
        assert info.value.field == field
    with pytest.raises(TypeError, match="config must be"):
        engine.Simulation(42)  # type: ignore[arg-type]
    with pytest.raises(FileNotFoundError):
        engine.Simulation(str(tmp_path / "missing.json"))


def test_configs_from_json_text_and_files(tmp_path: Path) -> None:
    cfg = engine.water_column(0.02, 0.1, 0.2)
    assert engine.validate_config(cfg) == cfg
    default = engine.default_config()
    assert default["scene"]["fluid_blocks"] == [] and default["dt"] == 1e-3
    assert engine.validate_config({}) == default
    text = json.dumps(cfg)
    path = tmp_path / "column.json"
    path.write_text(text, encoding="utf-8")
    for source in (text, str(path), path):
        assert engine.validate_config(source) == cfg
    sim = engine.Simulation(path, num_threads=1)
    assert sim.config == cfg and sim.particles("fluid")["positions"].shape == (3 * 3 * 5, 3)


def test_bad_particle_kind_lists_the_kinds(dam: dict[str, Any]) -> None:
    sim = engine.Simulation(dam, num_threads=1)
    with pytest.raises(ValueError, match="'fluid', 'porous' or 'boundary'"):
        sim.particles("solid")  # type: ignore[arg-type]
    with pytest.raises(rmi_sph.ConfigError) as info:
        sim.step(-1)
    assert info.value.field == "n"


def test_kinematic_body_moves_with_its_velocity() -> None:
    cfg = engine.water_column(0.02, 0.1, 0.2)
    cfg["scene"]["bodies"].append(
        {
            "name": "paddle",
            "shape": {"box": {"half_extents": [0.02, 0.02, 0.02]}},
            "position": [0.0, 0.0, 0.3],
            "kinematic": True,
        }
    )
    sim = engine.Simulation(cfg, num_threads=1)
    with pytest.raises(rmi_sph.ConfigError) as info:
        sim.set_body_velocity(0, (0.1, 0.0, 0.0))  # the tank is static
    assert info.value.field == "scene.bodies[0].kinematic"
    with pytest.raises(rmi_sph.ConfigError) as info:
        sim.set_body_velocity(2, (0.1, 0.0, 0.0))
    assert info.value.field == "body"
    with pytest.raises(rmi_sph.ConfigError):
        sim.set_body_velocity(1, (float("inf"), 0.0, 0.0))
    sim.set_body_velocity(1, (0.0, 0.0, -0.1))
    sim.step(10)
    paddle = sim.bodies()[1]
    assert paddle["kinematic"] and paddle["velocity"] == (0.0, 0.0, -0.1)
    assert paddle["position"][2] == pytest.approx(0.3 - 0.1 * 10 * sim.dt)


def test_ctrl_c_interrupts_step(dam: dict[str, Any]) -> None:
    sim = engine.Simulation(dam, num_threads=1)
    assert_interruptible(lambda: sim.step(10**7))
    assert 0 < sim.step_count < 10**7


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_forked_child_rebuilds_its_thread_pool(sponge: dict[str, Any]) -> None:
    sim = engine.Simulation(sponge, num_threads=2)
    sim.step(5)

    def child() -> bytes:
        sim.step(10)
        return sim.particles("porous")["positions"].tobytes()

    data = in_forked_child(child)
    sim.step(10)
    got = np.frombuffer(data, dtype=np.float64).reshape(-1, 3)
    assert same(got, sim.particles("porous")["positions"])


def test_deprecated_simulation_name_is_the_trial() -> None:
    with pytest.warns(DeprecationWarning, match=r"rmi_sph\.Trial"):
        cls = rmi_sph.Simulation
    assert cls is rmi_sph.Trial
    # `from rmi_sph import *` takes the new names without touching the deprecated one.
    namespace: dict[str, Any] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec("from rmi_sph import *", namespace)
    assert namespace["Trial"] is rmi_sph.Trial and namespace["engine"] is engine
    assert "Simulation" not in namespace
    with pytest.raises(AttributeError, match="no attribute 'Simulator'"):
        rmi_sph.Simulator  # noqa: B018
