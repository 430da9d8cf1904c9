"""The Python binding `rmi_sph`: configs, Trial, run_trial, state, threads, errors.

Scenes are tiny (8 cm sponge of porosity 0.8 at r = 10 mm, about 250 dynamic particles,
dt = 2 ms, short phases, a squeeze to 150 N that expels some water): a whole trial takes a
few seconds on a shared 2-core machine.
"""

from __future__ import annotations

import json
import os
import pickle
import threading
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import rmi_sph
from binding_util import assert_interruptible, in_forked_child, same
from rmi_learn.data.runs import RUN_COLUMNS, read_run, write_run
from rmi_learn.data.schema import ACTIONS, EXTRAS, OBS, PHASES
from tiny_trial import tiny_config


@pytest.fixture(scope="module")
def cfg() -> dict[str, Any]:
    return tiny_config()


@pytest.fixture(scope="module")
def trial(cfg: dict[str, Any]) -> dict[str, Any]:
    return rmi_sph.run_trial(cfg, num_threads=1)


# --------------------------------------------------------------------------------------
# Configs


def test_names_match_schema() -> None:
    assert rmi_sph.OBSERVATION_NAMES == OBS
    assert rmi_sph.EXTRA_NAMES == EXTRAS
    assert rmi_sph.ACTION_NAMES == ACTIONS


def test_default_and_trial_config(tmp_path: Path) -> None:
    d = rmi_sph.default_config()
    assert {"size", "porosity", "dt", "controller", "material", "gate"} <= set(d)
    for size_cm, x in [(8, 0.08), (10, 0.10), (12, 0.12)]:
        c = rmi_sph.trial_config(size_cm, 0.5, 30.0, 60.0)
        assert c["size"][0] == pytest.approx(x)
        assert (c["porosity"], c["hold_force"], c["squeeze_force"]) == (0.5, 30.0, 60.0)
        assert c["particle_radius"] == 0.005 and c["seed"] == 0
    c = rmi_sph.trial_config(
        8, 0.6, 20, 40, 0.01, 3, settle_time=0.07, material={"youngs_modulus": 3e5}, dt=2e-3
    )
    assert c["controller"]["settle_time"] == 0.07
    assert c["controller"]["ramp_time"] == d["controller"]["ramp_time"]
    assert c["material"]["youngs_modulus"] == 3e5
    assert c["material"]["permeability"] == d["material"]["permeability"]
    assert (c["seed"], c["dt"]) == (3, 2e-3)
    # Every accepted form of a config gives the same complete config.
    path = tmp_path / "c.json"
    path.write_text(json.dumps(c))
    assert rmi_sph.validate_config(c) == c
    assert rmi_sph.validate_config(json.dumps(c)) == c
    assert rmi_sph.validate_config(str(path)) == c
    assert rmi_sph.validate_config(path) == c
    assert rmi_sph.validate_config({"porosity": np.float64(0.5)})["porosity"] == 0.5
    # Integral floats are accepted for integer fields.
    assert rmi_sph.validate_config({"record_every": 4.0})["record_every"] == 4


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: rmi_sph.trial_config(9, 0.6, 20, 40), "size_cm"),
        (lambda: rmi_sph.trial_config(8, 0.99, 20, 40), "porosity"),
        (lambda: rmi_sph.trial_config(8, 0.6, -1, 40), "hold_force"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, bogus=1), "bogus"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, settle_time=-1), "controller.settle_time"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, material={"porosty": 1}), "material.porosty"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, gate={"k_stable": 2.5}), "gate.k_stable"),
        (lambda: rmi_sph.trial_config(8, 0.6, 20, 40, cg={"tolerance": 0.5}), "cg.tolerance"),
        (lambda: rmi_sph.validate_config({"dt": "fast"}), "dt"),
        (lambda: rmi_sph.validate_config({"size": [0.1, 0.1]}), "size"),
        (lambda: rmi_sph.validate_config({"controller": 3}), "controller"),
        (lambda: rmi_sph.validate_config({"dt": float("nan")}), "dt"),
        (lambda: rmi_sph.validate_config({"saturated": 1}), "saturated"),
        (lambda: rmi_sph.Trial({"friction": {"mu_kinetic": 5.0}}), "friction.mu_kinetic"),
        (lambda: rmi_sph.run_trial({"jitter": 0.9}), "jitter"),
        (lambda: rmi_sph.validate_config("{not json"), "trial"),
    ],
)
def test_bad_config_names_the_field(make: Any, field: str) -> None:
    with pytest.raises(rmi_sph.ConfigError) as info:
        make()
    assert info.value.field == field
    assert field in str(info.value)
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    ("call", "field", "value"),
    [
        (lambda c: rmi_sph.Trial(c).step(-1), "n", "-1"),
        (lambda c: rmi_sph.Trial(c, num_threads=-1), "num_threads", "-1"),
        (lambda c: rmi_sph.Trial(c, num_threads=2000), "num_threads", "2000"),
        (lambda c: rmi_sph.run_trial(c, num_threads=-2), "num_threads", "-2"),
        (lambda c: rmi_sph.run_trial(c, record_every=-3), "record_every", "-3"),
        (lambda c: rmi_sph.run_trial(c, record_every=2**40), "record_every", str(2**40)),
        (lambda c: rmi_sph.trial_config(8, 0.6, 20, 40, seed=-1), "seed", "-1"),
        (lambda c: rmi_sph.Trial.from_state(b"", num_threads=-4), "num_threads", "-4"),
    ],
)
def test_out_of_range_integers_name_the_argument(
    cfg: dict[str, Any], call: Any, field: str, value: str
) -> None:
    # Negative or oversized counts are ConfigErrors naming the argument and its range (not
    # the bare OverflowError of converting them to unsigned integers).
    with pytest.raises(rmi_sph.ConfigError) as info:
        call(cfg)
    assert (info.value.field, info.value.value) == (field, value)
    assert info.value.expected and "Overflow" not in str(info.value)


def test_state_file_errors_name_the_file(cfg: dict[str, Any], tmp_path: Path) -> None:
    missing = tmp_path / "missing.bin"
    with pytest.raises(FileNotFoundError) as info:
        rmi_sph.Trial.load(str(missing))
    assert info.value.filename == str(missing) and str(missing) in str(info.value)
    sim = rmi_sph.Trial(cfg)
    folder = tmp_path / "d"
    folder.mkdir()
    for target, kind in ((folder, IsADirectoryError), (folder / "no" / "s.bin", FileNotFoundError)):
        with pytest.raises(kind) as err:
            sim.save(str(target))
        assert err.value.filename == str(target)
    # The temporary file beside the target is gone too.
    assert [p.name for p in tmp_path.iterdir()] == ["d"] and not any(folder.iterdir())


def test_config_type_errors(tmp_path: Path) -> None:
    with pytest.raises(TypeError):
        rmi_sph.Trial(42)  # type: ignore[arg-type]
    with pytest.raises(FileNotFoundError):
        rmi_sph.Trial(str(tmp_path / "missing.json"))


_CONTROLLER_FIELDS = sorted(rmi_sph.default_config()["controller"])


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from(_CONTROLLER_FIELDS),
    value=st.floats(max_value=-1e-3, allow_nan=False, allow_infinity=False),
)
def test_property_negative_controller_values_are_refused(name: str, value: float) -> None:
    with pytest.raises(rmi_sph.ConfigError) as info:
        rmi_sph.validate_config({"controller": {name: value}})
    assert info.value.field == f"controller.{name}"


@settings(max_examples=40, deadline=None)
@given(key=st.text(min_size=1, max_size=12))
def test_property_unknown_keys_are_refused(key: str) -> None:
    defaults = rmi_sph.default_config()
    positional = {"size_cm", "porosity", "hold_force", "squeeze_force", "radius", "seed"}
    if key in defaults or key in defaults["controller"] or key in positional:
        return
    with pytest.raises(rmi_sph.ConfigError) as info:
        rmi_sph.trial_config(8, 0.6, 20, 40, **{key: 1.0})  # type: ignore[arg-type]
    assert info.value.field == key
    with pytest.raises(rmi_sph.ConfigError) as info:
        rmi_sph.validate_config({"gripper": {key: 1.0}})
    assert info.value.field == f"gripper.{key}"


# --------------------------------------------------------------------------------------
# Trial


def test_simulation_round_trip(cfg: dict[str, Any]) -> None:
    sim = rmi_sph.Trial(cfg, num_threads=1)
    assert sim.config == cfg
    first = sim.observation()
    assert (sim.time, sim.step_count, sim.phase, sim.finished, sim.failure) == (
        0.0,
        0,
        "settle",
        False,
        None,
    )
    assert sim.dt == cfg["dt"] and sim.num_threads == 1 and sim.time_limit > 1.0
    assert sim.step() == 1
    assert sim.step(59) == 59
    assert sim.step_count == 60 and sim.time == pytest.approx(0.12)
    assert sim.phase in PHASES and "Trial(" in repr(sim)
    obs = sim.observation()
    assert list(obs)[:23] == list(OBS)
    assert set(EXTRAS) | set(ACTIONS) <= set(obs)
    assert isinstance(obs["phase"], str) and isinstance(obs["gate_open"], bool)
    vec = sim.observation_vector()
    assert vec.shape == (23,) and vec.dtype == np.float64
    assert same(vec, np.array([obs[n] for n in OBS]))
    rec = sim.take_record()
    assert same(
        np.array([rec[n] for n in OBS if n not in ("F_L", "F_R", "F_meas", "alpha_F")]),
        np.array([obs[n] for n in OBS if n not in ("F_L", "F_R", "F_meas", "alpha_F")]),
    )

    fluid, solid, bnd = (sim.particles(k) for k in ("fluid", "solid", "boundary"))
    out = sim.outcome()
    nf, ns = out["n_fluid"], out["n_solid"]
    assert fluid["positions"].shape == (nf, 3) and solid["positions"].shape == (ns, 3)
    for d, n in [(fluid, nf), (solid, ns)]:
        for key in ("velocities", "mass", "density", "pressure", "porosity", "id"):
            assert d[key].shape[0] == n
        assert np.all(np.isfinite(d["density"])) and np.all(d["density"] > 0)
    assert "saturation" in solid and "saturation" not in fluid
    assert np.all((solid["saturation"] >= 0) & (solid["saturation"] <= 1))
    # Water under its own weight carries a positive pressure of the right order (Pa).
    assert fluid["pressure"].max() > 0 and fluid["pressure"].max() < 1e5
    assert np.sum(fluid["mass"]) == pytest.approx(out["total_water"])
    # The sponge starts holding all the water; what its pores lost since (rho_f V_pore S) is
    # expelled. "retained" is the part of each fluid particle inside the sponge's outline.
    assert first["M_L"] == out["total_water"] and first["M_expelled"] == 0.0
    lost = 1000.0 * (first["V_pore"] * first["S"] - obs["V_pore"] * obs["S"])
    assert obs["M_expelled"] == pytest.approx(max(lost, 0.0), rel=1e-9, abs=1e-12)
    part = fluid["retained"]
    assert part.dtype == np.float64 and part.shape == (nf,)
    assert np.all((part >= 0) & (part <= 1)) and np.sum(fluid["mass"] * part) > 0.9 * obs["M_L"]
    bodies = sim.bodies()
    assert [b["name"] for b in bodies] == ["floor", "pad_left", "pad_right"]
    assert bnd["positions"].shape[0] == bnd["body"].shape[0] == bnd["volume"].shape[0]
    assert set(np.unique(bnd["body"])) == {0, 1, 2}
    with pytest.raises(ValueError, match="unknown particle kind"):
        sim.particles("gas")  # type: ignore[arg-type]

    assert sim.action is None
    sim.set_action(15.0, 0.01)
    assert sim.action == (15.0, 0.01)
    sim.step(3)
    assert sim.observation()["F_target"] == 15.0
    sim.set_action(12.0)
    assert sim.action == (12.0, None)
    sim.clear_action()
    assert sim.action is None
    for bad, field in [
        ((-1.0,), "force_target"),
        ((10.0, 2.0), "velocity_command"),
        ((float("nan"),), "force_target"),
    ]:
        with pytest.raises(rmi_sph.ConfigError) as info:
            sim.set_action(*bad)
        assert info.value.field == field
    assert set(out) == {
        "lift_success", "stable_squeeze", "failure", "gate_opened_at", "water_removed",
        "initial_water", "final_water", "total_water", "sim_time", "steps", "wall_s",
        "n_fluid", "n_solid",
    }  # fmt: skip
    with pytest.raises(rmi_sph.StateError):
        sim.records()


def test_threads_give_bit_identical_results(cfg: dict[str, Any]) -> None:
    sims = [rmi_sph.Trial(cfg, num_threads=k) for k in (1, 2)]
    for _ in range(4):
        for s in sims:
            s.step(25)
        a, b = (s.observation_vector() for s in sims)
        assert same(a, b)
    assert sims[0].phase not in ("settle", "close")  # compared through contact
    for kind in ("fluid", "solid"):
        pa, pb = (s.particles(kind) for s in sims)
        for key in pa:
            assert same(pa[key], pb[key]), (kind, key)


def _continue(sim: rmi_sph.Trial, n: int = 30) -> tuple[np.ndarray, np.ndarray]:
    sim.step(n)
    return sim.observation_vector(), sim.particles("solid")["positions"]


def test_state_and_pickle_continue_identically(cfg: dict[str, Any], tmp_path: Path) -> None:
    sim = rmi_sph.Trial(cfg, num_threads=1)
    sim.step(70)  # in contact: friction memory, controller and gate state matter
    state = sim.get_state()
    assert isinstance(state, bytes)
    pickled = pickle.loads(pickle.dumps(sim))
    from_state = rmi_sph.Trial.from_state(state, num_threads=2)
    sim.save(tmp_path / "s.bin")
    loaded = rmi_sph.Trial.load(tmp_path / "s.bin", num_threads=1)
    with pytest.raises(rmi_sph.StateError, match="jitter"):
        rmi_sph.Trial(tiny_config(jitter=0.1), num_threads=1).set_state(state)
    other = rmi_sph.Trial(cfg, num_threads=1)
    other.set_state(state)
    assert other.config == cfg and other.time == sim.time and other.phase == sim.phase
    ref = _continue(sim)
    for s in (pickled, from_state, loaded, other):
        got = _continue(s)
        assert same(got[0], ref[0]) and same(got[1], ref[1])
    with pytest.raises(rmi_sph.StateError):
        sim.set_state(b"not a state")
    with pytest.raises(rmi_sph.StateError):
        sim.set_state(state[:100])
    with pytest.raises(FileNotFoundError):
        rmi_sph.Trial.load(tmp_path / "missing.bin")


def test_deprecated_name_and_its_pickles_still_work(cfg: dict[str, Any]) -> None:
    with pytest.warns(DeprecationWarning, match=r"rmi_sph\.Trial"):
        old_name = rmi_sph.Simulation
    sim = old_name(cfg, num_threads=1)
    assert type(sim) is rmi_sph.Trial
    sim.step(10)
    # Pickles from before the rename name the class `rmi_sph._rmi_sph.Simulation`; protocol 2
    # writes globals as text, so such a pickle is this one with the name swapped.
    new = pickle.dumps(sim, protocol=2)
    assert b"crmi_sph._rmi_sph\nTrial\n" in new
    old = new.replace(b"crmi_sph._rmi_sph\nTrial\n", b"crmi_sph._rmi_sph\nSimulation\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        restored = pickle.loads(old)
    assert type(restored) is rmi_sph.Trial
    ref = _continue(sim)
    got = _continue(restored)
    assert same(got[0], ref[0]) and same(got[1], ref[1])


def test_step_releases_the_gil(cfg: dict[str, Any]) -> None:
    sim = rmi_sph.Trial(cfg, num_threads=1)
    sim.step(5)
    ticks = 0
    stop = threading.Event()

    def spin() -> None:
        nonlocal ticks
        while not stop.is_set():
            ticks += 1
            time.sleep(0.001)

    thread = threading.Thread(target=spin)
    thread.start()
    t0 = time.perf_counter()
    sim.step(100)
    elapsed = time.perf_counter() - t0
    stop.set()
    thread.join()
    # The thread sleeps 1 ms per tick; with the GIL held it would hardly run at all.
    assert ticks >= max(5, int(0.2 * elapsed / 0.0011)), (ticks, elapsed)


def test_ctrl_c_interrupts_step_and_run_trial(cfg: dict[str, Any]) -> None:
    sim = rmi_sph.Trial(cfg, num_threads=1)
    assert_interruptible(lambda: sim.step(10**7))
    assert 0 < sim.step_count < 10**7
    long = tiny_config(settle_time=50.0)
    assert_interruptible(lambda: rmi_sph.run_trial(long, num_threads=1))


def test_panics_become_rmi_errors() -> None:
    with pytest.raises(rmi_sph.RmiError, match="panic"):
        rmi_sph._raise_error("panic")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_forked_child_rebuilds_its_thread_pool(cfg: dict[str, Any]) -> None:
    sim = rmi_sph.Trial(cfg, num_threads=2)
    sim.step(10)

    def child() -> bytes:
        sim.step(20)
        return sim.observation_vector().tobytes()

    data = in_forked_child(child)
    sim.step(20)
    assert same(np.frombuffer(data, dtype=np.float64), sim.observation_vector())


# --------------------------------------------------------------------------------------
# run_trial and recording


def test_run_trial_columns_follow_the_contract(
    trial: dict[str, Any], cfg: dict[str, Any], tmp_path: Path
) -> None:
    cols, out = trial["columns"], trial["outcome"]
    assert tuple(cols) == RUN_COLUMNS
    n = len(cols["time"])
    assert n > 10 and all(len(v) == n for v in cols.values())
    assert cols["phase"].dtype.kind == "U" and cols["gate_open"].dtype == np.bool_
    for name, v in cols.items():
        if name in ("phase", "gate_open"):
            continue
        assert v.dtype == np.float64, name
        if name != "v_res":
            assert np.all(np.isfinite(v)), name
    assert np.all(np.diff(cols["time"]) > 0)
    # v_res is NaN exactly where no skeleton particle touches a pad.
    assert np.all(np.isnan(cols["v_res"]) == (cols["r_none"] == 1.0))
    assert set(cols["phase"]) <= set(PHASES)
    assert list(dict.fromkeys(cols["phase"])) == [p for p in PHASES if p in set(cols["phase"])]
    # Liquid mass is conserved: retained + expelled = the water present at the start.
    assert cols["M_expelled"][-1] > cols["M_expelled"][0] + 1e-3  # the squeeze expelled water (kg)
    total = cols["M_L"] + cols["M_expelled"]
    np.testing.assert_allclose(total, out["total_water"], rtol=1e-12)
    assert out["initial_water"] == cols["M_L"][0] and out["final_water"] == cols["M_L"][-1]
    assert out["lift_success"] and out["stable_squeeze"] and out["failure"] is None
    assert list(out["water_removed"]) == [p for p in PHASES if p != "done"]
    assert sum(out["water_removed"].values()) == pytest.approx(
        out["initial_water"] - out["final_water"], abs=1e-12
    )
    assert out["steps"] == round(out["sim_time"] / cfg["dt"])
    # The columns are a valid run file.
    params = {"size_cm": 8, "porosity": 0.8, "F_hold": 20.0, "F_squeeze": 150.0, "seed": 0}
    path = write_run(tmp_path / "run.parquet", cols, cfg, params, out)
    df, meta = read_run(path)
    assert df.height == n and meta["outcome"]["final_water"] == out["final_water"]


def test_squeeze_group_members_equal_their_own_trials(
    trial: dict[str, Any], cfg: dict[str, Any]
) -> None:
    # One shared prefix, then each squeeze force: every member has the bits of run_trial
    # with that force (the config's own squeeze force, 150 N, is the fixture's trial).
    group = rmi_sph.run_squeeze_group(cfg, [60.0, cfg["squeeze_force"]], num_threads=2)
    assert len(group) == 2
    alone = rmi_sph.run_trial({**cfg, "squeeze_force": 60.0}, num_threads=1)
    for member, own in [(group[0], alone), (group[1], trial)]:
        assert tuple(member["columns"]) == tuple(own["columns"])
        for name, column in own["columns"].items():
            assert same(member["columns"][name], column), name
        strip = lambda o: {k: v for k, v in o.items() if k != "wall_s"}  # noqa: E731
        assert strip(member["outcome"]) == strip(own["outcome"])
    removed = [g["outcome"]["water_removed"]["squeeze"] for g in group]
    assert removed[0] != removed[1]
    with pytest.raises(rmi_sph.ConfigError) as info:
        rmi_sph.run_squeeze_group(cfg, [60.0, 500.0])
    assert info.value.field == "squeeze_forces[1]"
    perturbed = {**cfg, "controller": {**cfg["controller"], "perturbation": {"enabled": True}}}
    with pytest.raises(rmi_sph.ConfigError) as info:
        rmi_sph.run_squeeze_group(perturbed, [60.0])
    assert info.value.field == "controller.perturbation.enabled"


def test_record_every_override(cfg: dict[str, Any]) -> None:
    short = dict(cfg, controller=dict(cfg["controller"], squeeze_hold_time=0.0))
    a = rmi_sph.run_trial(short, num_threads=1, record_every=25)
    assert np.allclose(np.diff(a["columns"]["time"])[:-1], 25 * cfg["dt"])
    with pytest.raises(rmi_sph.ConfigError, match="record_every"):
        rmi_sph.run_trial(short, record_every=0)


def test_stepping_with_recording_equals_run_trial(
    trial: dict[str, Any], cfg: dict[str, Any]
) -> None:
    sim = rmi_sph.Trial(cfg, num_threads=2, record=True)
    with pytest.raises(rmi_sph.StateError):
        sim.take_record()
    while not sim.finished:
        sim.step(37, stop_at_finish=True)
    assert sim.step(5, stop_at_finish=True) == 0
    cols = sim.records()
    assert tuple(cols) == RUN_COLUMNS
    for name in RUN_COLUMNS:
        assert same(cols[name], trial["columns"][name]), name
    out = sim.outcome()
    for key in ("lift_success", "stable_squeeze", "final_water", "steps", "water_removed"):
        assert out[key] == trial["outcome"][key]
    sim.records(clear=True)
    assert len(sim.records()["time"]) == 0
