"""The sweep with the real engine (not a test double): the `tiny` preset end to end."""

from __future__ import annotations

import math
from pathlib import Path

import polars as pl
import pytest

import rmi_sph
from rmi_learn.data import schema
from rmi_learn.data.runs import read_run, run_path
from rmi_learn.data.sweep import (
    PRESETS,
    configs_of,
    expand_grid,
    load_grid,
    prefix_groups,
    run_sweep,
    validate_grid,
)
from rmi_learn.sim.replay import control_substeps


def test_tiny_preset_runs_with_the_engine_and_resumes(tmp_path: Path) -> None:
    grid = load_grid("tiny")
    specs = expand_grid(grid)
    out = tmp_path / "grid"
    res = run_sweep(specs, out, workers=2, threads_per_run=1, progress=False, grid=grid)
    assert res.ok == len(specs) and res.failed == 0
    index = pl.read_parquet(out / "index.parquet")
    assert index.height == len(specs)
    assert index["status"].to_list() == ["ok"] * len(specs)
    for path in index["path"].to_list():
        frame, meta = read_run(out / path if not Path(path).is_absolute() else path)
        assert set(frame.columns) == set(schema.EXTRAS) | set(schema.OBS) | set(schema.ACTIONS)
        total = (frame["M_L"] + frame["M_expelled"]).to_numpy()
        assert all(math.isclose(x, total[0], rel_tol=0, abs_tol=1e-12) for x in total)
        assert meta["outcome"]["initial_water"] > 0
    # A second sweep over the same directory does nothing and loses nothing.
    again = run_sweep(specs, out, workers=2, threads_per_run=1, progress=False, grid=grid)
    assert again.ok == 0 and again.skipped == len(specs)
    # The README's polars query over the grid.
    q = (
        pl.scan_parquet(out / "index.parquet")
        .filter(pl.col("status") == "ok")
        .group_by("porosity", "F_hold")
        .agg(pl.col("lift_success").mean())
        .collect()
    )
    assert q.height == len({(s.params["porosity"], s.params["F_hold"]) for s in specs})


def test_runs_sharing_their_prefix_equal_the_runs_made_alone(tmp_path: Path) -> None:
    # Two squeeze forces per (porosity, hold): the engine's runner runs each pair from one
    # shared prefix; an injected runner (the same engine function) runs every trial alone.
    # 10 N drops the porosity-0.7 sponge before the squeeze: both members end so.
    grid = {**load_grid("tiny"), "hold_forces_N": [10, 60], "squeeze_forces_N": [120, 200]}
    specs = expand_grid(grid)
    assert len(prefix_groups(specs, configs_of(specs))) == len(specs) // 2
    shared, alone = tmp_path / "shared", tmp_path / "alone"
    a = run_sweep(specs, shared, workers=2, progress=False, grid=grid)
    b = run_sweep(specs, alone, workers=0, runner=rmi_sph.run_trial, progress=False, grid=grid)
    assert a.ok == b.ok == len(specs)
    for spec in specs:
        fa, ma = read_run(run_path(shared / "runs", spec.params))
        fb, mb = read_run(run_path(alone / "runs", spec.params))
        assert fa.equals(fb), spec.run_id
        timing = ("wall_s", "sweep_wall_s")
        oa, ob = ({k: v for k, v in m["outcome"].items() if k not in timing} for m in (ma, mb))
        assert oa == ob and ma["config"] == mb["config"], spec.run_id
        # Shared: the group's wall time split evenly (alone, each run timed its own).
        pair = [ma] + [
            read_run(run_path(shared / "runs", {**spec.params, "F_squeeze": f}))[1]
            for f in grid["squeeze_forces_N"]
            if f != spec.params["F_squeeze"]
        ]
        assert len({m["outcome"]["sweep_wall_s"] for m in pair}) == 1, spec.run_id
    lifted = pl.read_parquet(shared / "index.parquet")["lift_success"].to_list()
    assert True in lifted and False in lifted


def test_a_grid_the_engine_refuses_fails_before_any_run(tmp_path: Path) -> None:
    # An override out of range would fail every run one by one; it is found up front,
    # naming a run and the field, and nothing is written.
    grid = {**load_grid("tiny"), "overrides": {"dt": -1.0}}
    out = tmp_path / "grid"
    with pytest.raises(ValueError, match=r"run size_cm=8/.*`dt` = -1.*no run was started"):
        run_sweep(expand_grid(grid), out, workers=0, progress=False, grid=grid)
    assert not out.exists()


def test_perturbed_seeds_follow_their_own_force_targets_from_the_lift_on(tmp_path: Path) -> None:
    grid = load_grid("tiny")
    grid = {
        **grid,
        "porosities": [0.5],
        "hold_forces_N": [60],
        "seeds": [0, 1],
        "perturbation": {"seeds": [1], "max_force": 150.0},
    }
    grid = validate_grid(grid)
    specs = expand_grid(grid)
    out = tmp_path / "grid"
    res = run_sweep(specs, out, workers=2, threads_per_run=1, progress=False, grid=grid)
    assert res.ok == 2
    index = pl.read_parquet(out / "index.parquet").sort("seed")
    assert index["perturbed"].to_list() == [False, True]
    frames = {s: read_run(out / p)[0] for s, p in zip(index["seed"], index["path"], strict=True)}
    air = {
        s: f.filter(pl.col("phase").is_in(["lift", "waiting", "squeeze"]))["F_target"].to_numpy()
        for s, f in frames.items()
    }
    # Scripted: the hold force, then the ramp to the squeeze force. Perturbed: many levels
    # within [0.8 F_hold, max_force], the recorded actions being those commands.
    assert abs(air[0][: len(air[0]) // 4] - 60.0).max() < 1e-9
    assert air[1].min() >= 0.8 * 60 - 1e-9 and air[1].max() <= 150 + 1e-9
    assert len(set(air[1].round(3))) > 5
    hold = {
        s: f.filter(pl.col("phase") == "hold")["F_target"].to_numpy() for s, f in frames.items()
    }
    # (a row's value is the last step's command; the first hold row ends the smooth ramp)
    assert abs(hold[1] - 60.0).max() < 0.01, "the hold on the floor stays scripted"
    # Resuming with the same grid is a no-op; the physical tables leave the perturbed run out.
    again = run_sweep(specs, out, workers=0, progress=False, grid=grid)
    assert again.skipped == 2
    from rmi_learn.analysis.run_table import load_runs

    assert load_runs(out).index["seed"].to_list() == [0]


def test_a_perturbation_of_seeds_outside_the_grid_is_refused() -> None:
    grid = {**load_grid("tiny"), "perturbation": {"seeds": [5]}}
    with pytest.raises(ValueError, match=r"perturbation.seeds must be .* grid's seeds \[0\]"):
        validate_grid(grid)
    grid = {**load_grid("tiny"), "perturbation": {"seeds": [0], "seed": 3}}
    with pytest.raises(ValueError, match=r"perturbation.seed is set by the sweep"):
        validate_grid(grid)
    bad = {**load_grid("tiny"), "perturbation": {"seeds": [0], "ramp_probability": 2}}
    with pytest.raises(ValueError, match=r"perturbation.ramp_probability"):
        run_sweep(expand_grid(validate_grid(bad)), "/nonexistent/x", workers=0, progress=False)


@pytest.mark.parametrize("preset", PRESETS)
def test_every_preset_time_step_divides_the_control_step(preset: str) -> None:
    # Closed-loop replay and the goal-reaching benchmark act every CONTROL_DT on engine steps.
    # The time step is the one the engine configures for the run (its default where unset).
    grid = load_grid(preset)
    first_of_size = {}
    for s in expand_grid(grid):
        first_of_size.setdefault(s.params["size_cm"], s)
    for size, spec in first_of_size.items():
        p = spec.params
        cfg = rmi_sph.trial_config(
            size, p["porosity"], p["F_hold"], p["F_squeeze"], spec.radius, p["seed"],
            **spec.overrides,
        )  # fmt: skip
        dt = float(cfg["dt"])
        assert control_substeps(dt) * dt == pytest.approx(schema.CONTROL_DT, rel=1e-12)
