"""Sweep machinery: grids, resumable idempotent runs, failures, kill -9 recovery, index, Ray.

The engine's ``rmi_sph.run_trial`` is replaced by TEST DOUBLES defined here (``fake_runner``,
``fake_make_config``): they return the toy ODE trial of ``rmi_learn.data.synthetic`` with the exact
run-file columns, and fail on purpose for some parameters. An end-to-end test with the real
engine belongs next to the engine's trial runner.
"""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pytest

from rmi_learn.cli import main as cli_main
from rmi_learn.data.runs import iter_run_files, read_run, run_path, scan_runs
from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.data.sweep import (
    INDEX_FILE,
    RUNS_SUBDIR,
    RunSpec,
    build_index,
    compute_group,
    estimate_wall_time,
    expand_grid,
    load_grid,
    longest_first,
    prefix_groups,
    run_sweep,
    validate_grid,
    with_later_fields,
)
from rmi_learn.data.synthetic import simulate_toy_run

TESTS = Path(__file__).resolve().parent
FAIL_HOLD = 50.0  # the double raises RuntimeError for this holding force
UNSTABLE_SQUEEZE = 390.0  # ... and SimulationUnstableError for this squeeze force


class SimulationUnstableError(RuntimeError):
    """Stands in for rmi_sph.SimulationUnstableError (matched by class name)."""


# ---- test doubles (module level: spawned workers import them by name) -------------------


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


# ---- grids ---------------------------------------------------------------------------------


def test_presets() -> None:
    paper = load_grid("paper")
    assert len(expand_grid(paper)) == 594
    assert paper["sizes_cm"] == [8, 10, 12] and paper["porosities"] == [0.5, 0.6, 0.7]
    assert len(paper["hold_forces_N"]) == 11 and len(paper["squeeze_forces_N"]) == 6
    assert min(paper["hold_forces_N"]) <= 20 and max(paper["hold_forces_N"]) >= 200
    assert 280 <= max(paper["squeeze_forces_N"]) <= FORCE_LIMIT_N
    # The paper's own resolution, same runs; and the timing sample of studies/grids, which
    # must stay a subset of the preset at its resolution and timings.
    fine = load_grid("paper-fine")
    assert fine["radius_m"] == 0.0025 and "dt" not in fine["overrides"]
    assert [s.run_id for s in expand_grid(fine)] == [s.run_id for s in expand_grid(paper)]
    assert fine["radius_m"] < paper["radius_m"]
    sample = load_grid(path=Path(__file__).parents[2] / "studies" / "grids" / "paper-sample.json")
    assert (sample["radius_m"], sample["overrides"]) == (paper["radius_m"], paper["overrides"])
    assert sample["overrides_by_size"] == paper["overrides_by_size"]
    # Per size the converged time step (docs/engine.md): 2 ms for 8 cm, 2.5 ms above.
    dts = {s.params["size_cm"]: s.overrides["dt"] for s in expand_grid(paper)}
    assert dts == {8: 0.002, 10: 0.0025, 12: 0.0025}
    assert "overrides_by_size" not in fine
    assert {s.run_id for s in expand_grid(sample)} < {s.run_id for s in expand_grid(paper)}
    quick, tiny = load_grid("quick"), load_grid("tiny")
    assert 1 < len(expand_grid(tiny)) < len(expand_grid(quick)) < 594
    assert quick["radius_m"] > paper["radius_m"] and tiny["radius_m"] >= quick["radius_m"]
    # A preset is a file: the same file through path= gives the same grid.
    import rmi_learn.data.grids as g

    assert load_grid(path=Path(g.__file__).parent / "quick.json") == quick
    # The control grid: the quick grid's points with three seeds, two of them perturbed.
    control = expand_grid(load_grid("control"))
    assert len(control) == 3 * len(expand_grid(quick))
    perturbed = [s for s in control if "perturbation" in s.overrides]
    assert {s.params["seed"] for s in perturbed} == {1, 2} and len(perturbed) == 2 * 24
    assert all(s.overrides["perturbation"] == {"enabled": True, "seed": s.params["seed"]}
               for s in perturbed)  # fmt: skip


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"hold_forces_N": [10, 401]}, "outside"),
        ({"sizes_cm": [9]}, "sizes_cm"),
        ({"porosities": [1.2]}, "porosity"),
        ({"seeds": [0, 0]}, "duplicates"),
        ({"colour": "red"}, "unknown keys"),
        ({"overrides_by_size": {"10": {"dt": 0.003}}}, "overrides_by_size key '10'"),
        ({"overrides_by_size": {"eight": {}}}, "overrides_by_size key 'eight'"),
        ({"overrides_by_size": {"8": 0.003}}, r"overrides_by_size\['8'\] must be an object"),
        ({"overrides_by_size": [0.003]}, "overrides_by_size must be an object"),
    ],
)
def test_grid_validation(change: dict[str, Any], message: str) -> None:
    base = {
        "sizes_cm": [8],
        "porosities": [0.5],
        "hold_forces_N": [10],
        "squeeze_forces_N": [50],
        "seeds": [0],
        "radius_m": 0.005,
    }
    with pytest.raises(ValueError, match=message):
        validate_grid({**base, **change})


def test_overrides_by_size_apply_to_their_size_only_and_win_over_overrides() -> None:
    g = grid(
        overrides={"dt": 0.002, "hold_time": 1.0},
        overrides_by_size={" 10": {"dt": 0.0025}},
        seeds=[0, 1],
        perturbation={"seeds": [1]},
    )
    assert g["overrides_by_size"] == {"10": {"dt": 0.0025}}
    for spec in expand_grid(g):
        dt = 0.0025 if spec.params["size_cm"] == 10 else 0.002
        assert spec.overrides["dt"] == dt and spec.overrides["hold_time"] == 1.0
        assert ("perturbation" in spec.overrides) == (spec.params["seed"] == 1)
    # A grid without the key keeps its earlier normal form (resumed sweeps compare grids).
    assert "overrides_by_size" not in grid()


def test_estimate_wall_time() -> None:
    assert estimate_wall_time(60.0, 594, 2) == 297 * 60.0
    assert estimate_wall_time(10.0, 5, 8) == 10.0


def test_longest_first_starts_the_largest_sponges_and_keeps_grid_order_among_equals() -> None:
    specs = expand_grid(load_grid("quick"))
    ordered = longest_first(specs)
    assert sorted(s.run_id for s in ordered) == sorted(s.run_id for s in specs)
    sizes = [s.params["size_cm"] for s in ordered]
    assert sizes == sorted(sizes, reverse=True)
    twelve = [s.run_id for s in specs if s.params["size_cm"] == 12]
    assert [s.run_id for s in ordered[: len(twelve)]] == twelve
    # A finer radius has more particles than a larger sponge at a coarser one.
    fine = RunSpec(specs[0].params, radius=specs[0].radius / 2)
    assert longest_first([*specs, fine])[0] is fine


# ---- local sweep ---------------------------------------------------------------------------


def test_prefix_groups_and_a_failing_group_falls_back_to_runs_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import rmi_sph

    specs = expand_grid(grid(hold_forces_N=[30], squeeze_forces_N=[150, UNSTABLE_SQUEEZE]))
    configs = {s.run_id: fake_make_config(**_trial_args(s)) for s in specs}
    groups = prefix_groups(specs, configs)
    assert [len(g) for g in groups] == [2, 2, 2, 2]  # 2 sizes x 2 porosities
    assert all(len(g) == 1 for g in prefix_groups(specs, configs, runner=fake_runner))
    perturbed = {
        k: {**c, "controller": {"perturbation": {"enabled": True}}} for k, c in configs.items()
    }
    assert all(len(g) == 1 for g in prefix_groups(specs, perturbed))

    # A member that fails makes the group raise: each run is then computed alone, and only
    # the failing one is recorded as failing.
    def group_raises(*_: Any, **__: Any) -> Any:
        raise SimulationUnstableError("velocity blew up in a member's squeeze")

    monkeypatch.setattr(rmi_sph, "run_squeeze_group", group_raises)
    monkeypatch.setattr(rmi_sph, "run_trial", fake_runner)
    g = groups[0]
    results = compute_group(g, [configs[s.run_id] for s in g])
    assert [r["run_id"] for r in results] == [s.run_id for s in g]
    assert [r["status"] for r in results] == ["ok", "unstable"]


def _trial_args(spec: RunSpec) -> dict[str, Any]:
    p = spec.params
    return {
        "size_cm": p["size_cm"],
        "porosity": p["porosity"],
        "hold_force": p["F_hold"],
        "squeeze_force": p["F_squeeze"],
        "radius": spec.radius,
        "seed": p["seed"],
    }


def test_local_sweep_records_failures_skips_done_and_indexes(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    log = tmp_path / "log.txt"
    g = grid(squeeze_forces_N=[150, UNSTABLE_SQUEEZE], overrides={"log": str(log)})
    specs = expand_grid(g)
    res = run_sweep(
        specs,
        out,
        runner=fake_runner,
        make_config=fake_make_config,
        workers=2,
        threads_per_run=3,
        progress=False,
        grid=g,
    )
    n = len(specs)  # 2 sizes x 2 porosities x 3 holds x 2 squeezes = 24
    assert n == 24 and res.total == n and res.skipped == 0
    assert res.failed == 8 and res.unstable == 8 and res.ok == 8  # FAIL_HOLD wins over 390 N
    assert len(logged(log)) == n
    idx = pl.read_parquet(out / INDEX_FILE)
    assert idx.height == n and idx["run_id"].n_unique() == n
    assert idx.equals(res.index)
    failed = idx.filter(pl.col("status") == "failed")
    assert (failed["F_hold"] == FAIL_HOLD).all() and failed.height == 8
    assert failed["error"].str.contains("RuntimeError: boom").all()
    unstable = idx.filter(pl.col("status") == "unstable")
    assert (unstable["F_squeeze"] == UNSTABLE_SQUEEZE).all()
    assert unstable["error"].str.contains("SimulationUnstableError").all()
    ok = idx.filter(pl.col("status") == "ok")
    assert ok["error"].is_null().all() and (ok["num_threads"] == 3).all()
    assert (ok["particles_fluid"] == 100 * ok["size_cm"]).all()
    assert ok["initial_water"].gt(ok["final_water"]).all()
    assert ok["water_removed_ramp"].gt(0).all() and ok["n_records"].gt(100).all()
    # Every ok row points at a run file whose metadata matches the row.
    for row in ok.iter_rows(named=True):
        _, meta = read_run(out / row["path"])
        assert meta["params"]["F_hold"] == row["F_hold"]
        assert meta["outcome"]["lift_success"] == row["lift_success"]
        assert meta["config"]["radius"] == 0.01
    # Second sweep: everything is done, nothing runs.
    again = run_sweep(
        specs,
        out,
        runner=fake_runner,
        make_config=fake_make_config,
        workers=2,
        progress=False,
        grid=g,
    )
    assert again.skipped == n and again.ok == again.failed == 0
    assert len(logged(log)) == n
    # Retrying failures reruns only them.
    retry = run_sweep(
        specs,
        out,
        runner=fake_runner,
        make_config=fake_make_config,
        workers=0,
        retry_failed=True,
        progress=False,
        grid=g,
    )
    assert retry.skipped == 8 and retry.failed == 8 and retry.unstable == 8
    assert len(logged(log)) == n + 16
    # The index is derived from the run directories: delete it and it comes back the same.
    (out / INDEX_FILE).unlink()
    assert build_index(out).equals(retry.index)
    assert retry.index.drop("wall_s", "error").equals(idx.drop("wall_s", "error"))
    # Another grid into the same directory is refused.
    with pytest.raises(ValueError, match="another grid"):
        run_sweep(
            specs,
            out,
            runner=fake_runner,
            make_config=fake_make_config,
            workers=0,
            progress=False,
            grid=grid(seeds=[1]),
        )


def other_engine_make_config(*args: Any, **overrides: Any) -> dict[str, Any]:
    """The same grid point as ``fake_make_config`` builds, on an engine whose default
    permeability changed."""
    return {**fake_make_config(*args, **overrides), "material": {"permeability": 3e-11}}


def test_resume_refuses_runs_of_another_engine_config(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    g = grid(hold_forces_N=[30], porosities=[0.5])
    sweep = functools.partial(
        run_sweep, expand_grid(g), out, runner=fake_runner, workers=0, progress=False, grid=g
    )
    sweep(make_config=fake_make_config)
    before = {p: p.read_bytes() for p in (out / "runs").rglob("*.parquet")}
    with pytest.raises(
        ValueError, match=r"2 finished run\(s\).*material: <absent> -> \{'permeability': 3e-11\}"
    ):
        sweep(make_config=other_engine_make_config)
    # Nothing was touched: the old runs stay as they were.
    assert {p: p.read_bytes() for p in (out / "runs").rglob("*.parquet")} == before


def test_a_stored_config_without_later_fields_reads_as_their_defaults() -> None:
    import rmi_sph

    default = rmi_sph.default_config()
    stored = json.loads(json.dumps(default))
    del stored["pressure"]["single_solve"]
    del stored["controller"]["perturbation"]
    assert with_later_fields(stored, default) == default
    # A stored value is kept: a run made with the option on stays different.
    stored["pressure"]["single_solve"] = True
    assert with_later_fields(stored, default)["pressure"]["single_solve"] is True


def test_polars_queries_over_the_grid(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    g = grid(hold_forces_N=[20, 150], squeeze_forces_N=[150, 300])
    run_sweep(
        expand_grid(g),
        out,
        runner=fake_runner,
        make_config=fake_make_config,
        workers=0,
        progress=False,
        grid=g,
    )
    # Lift success by porosity and holding force, from the index.
    table = (
        pl.scan_parquet(out / INDEX_FILE)
        .filter(pl.col("status") == "ok")
        .group_by("porosity", "F_hold")
        .agg(pl.col("lift_success").mean().alias("lift_rate"), pl.len().alias("runs"))
        .sort("porosity", "F_hold")
        .collect()
    )
    assert table.height == 4 and (table["runs"] == 4).all()
    rate = {(r["porosity"], r["F_hold"]): r["lift_rate"] for r in table.iter_rows(named=True)}
    assert rate[(0.5, 150.0)] == 1.0 and rate[(0.7, 20.0)] == 0.0  # the toy rule
    # The same from the time series, through hive partitions: water left at the end.
    final = (
        scan_runs(out / RUNS_SUBDIR)
        .group_by("size_cm", "porosity", "F_hold", "F_squeeze", "seed")
        .agg(pl.col("M_L").last().alias("m_end"))
        .collect()
    )
    assert final.height == len(expand_grid(g))
    idx = pl.read_parquet(out / INDEX_FILE)
    joined = final.join(idx, on=["size_cm", "porosity", "F_hold", "F_squeeze", "seed"])
    np.testing.assert_allclose(joined["m_end"], joined["final_water"])


def test_run_file_refusal_is_a_recorded_failure(tmp_path: Path) -> None:
    g = grid(sizes_cm=[8], porosities=[0.5], hold_forces_N=[150])
    res = run_sweep(
        expand_grid(g),
        tmp_path / "s",
        runner=nan_runner,
        make_config=fake_make_config,
        workers=0,
        progress=False,
    )
    assert res.failed == 1
    err = res.index["error"][0]
    assert "RunFileError" in err and "'F_L'" in err
    assert not list(iter_run_files(tmp_path / "s"))


def test_missing_engine_runner_is_a_clear_failure(tmp_path: Path) -> None:
    g = grid(sizes_cm=[8], porosities=[0.5], hold_forces_N=[150])
    res = run_sweep(
        expand_grid(g),
        tmp_path / "s",
        runner="rmi_sph:no_such_runner",
        make_config=fake_make_config,
        workers=0,
        progress=False,
    )
    assert res.failed == 1 and "no_such_runner" in res.index["error"][0]


def test_cli_sweep_and_index_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gfile = tmp_path / "g.json"
    gfile.write_text(json.dumps(grid(sizes_cm=[8], hold_forces_N=[30, 150])))
    out = tmp_path / "out"
    argv = [
        "sweep",
        "--grid",
        str(gfile),
        "--out",
        str(out),
        "--workers",
        "0",
        "--no-progress",
        "--runner",
        "test_sweep:fake_runner",
        "--make-config",
        "test_sweep:fake_make_config",
    ]
    assert cli_main(argv) == 0
    assert "4 runs: 0 already done, 4 ok" in capsys.readouterr().out
    assert cli_main(argv) == 0
    assert "4 runs: 4 already done" in capsys.readouterr().out
    (out / INDEX_FILE).unlink()
    assert cli_main(["sweep", "--out", str(out), "--index-only"]) == 0
    assert pl.read_parquet(out / INDEX_FILE).height == 4
    assert cli_main(["sweep", "--out", str(out)]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({**grid(), "squeeze_forces_N": [500]}))
    assert cli_main(["sweep", "--grid", str(bad), "--out", str(out)]) == 2


# ---- kill -9 and resume --------------------------------------------------------------------


def test_kill_9_midway_then_resume_loses_nothing(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    log = tmp_path / "log.txt"
    g = grid(
        sizes_cm=[8, 10, 12], hold_forces_N=[30, 150], overrides={"sleep": 0.25, "log": str(log)}
    )
    specs = expand_grid(g)  # 12 runs
    gfile = tmp_path / "grid.json"
    gfile.write_text(json.dumps(g))
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
    }
    cmd = [
        sys.executable,
        "-m",
        "rmi_learn.cli",
        "sweep",
        "--grid",
        str(gfile),
        "--out",
        str(out),
        "--workers",
        "2",
        "--no-progress",
        "--runner",
        "test_sweep:fake_runner",
        "--make-config",
        "test_sweep:fake_make_config",
    ]
    proc = subprocess.Popen(
        cmd, env=env, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    deadline = time.monotonic() + 60
    while len(list(iter_run_files(out))) < 3:
        assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
        assert time.monotonic() < deadline, "sweep made no progress"
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the sweep and its workers, mid-run
    proc.wait()
    done_before = {p.parent for p in iter_run_files(out)}
    assert 3 <= len(done_before) < len(specs)
    # What a writer killed mid-write leaves behind.
    stale = run_path(out / RUNS_SUBDIR, specs[-1].params).parent / ".run.parquet.x1y2.tmp"
    stale.parent.mkdir(parents=True, exist_ok=True)
    stale.write_bytes(b"PAR1 half a file")
    starts_before = len(logged(log))

    res = run_sweep(
        specs,
        out,
        runner=fake_runner,
        make_config=fake_make_config,
        workers=0,
        progress=False,
        grid=g,
    )
    assert res.skipped == len(done_before) and res.ok == len(specs) - len(done_before)
    files = list(iter_run_files(out))
    assert len(files) == len(specs) and len({f.parent for f in files}) == len(specs)
    for f in files:
        read_run(f)  # every file complete and readable
    assert not list(out.rglob("*.tmp"))
    idx = pl.read_parquet(out / INDEX_FILE)
    assert idx.height == len(specs) and (idx["status"] == "ok").all()
    assert idx["run_id"].n_unique() == len(specs)
    # Runs finished before the kill were not run again: only the rest started anew.
    assert len(logged(log)) - starts_before == len(specs) - len(done_before)


# ---- Ray -----------------------------------------------------------------------------------


def test_ray_backend_on_a_small_grid(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    g = grid(sizes_cm=[8], porosities=[0.5, 0.7], hold_forces_N=[30, FAIL_HOLD])
    res = run_sweep(
        expand_grid(g),
        tmp_path / "s",
        runner=fake_runner,
        make_config=fake_make_config,
        backend="ray",
        threads_per_run=1,
        progress=False,
        grid=g,
    )
    assert res.total == 4 and res.ok == 2 and res.failed == 2
    assert (res.index.filter(pl.col("status") == "ok")["num_threads"] == 1).all()


def test_ray_missing_gives_a_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    g = grid(sizes_cm=[8], porosities=[0.5], hold_forces_N=[30])
    with pytest.raises(RuntimeError, match="pip install"):
        run_sweep(
            expand_grid(g),
            tmp_path / "s",
            runner=fake_runner,
            make_config=fake_make_config,
            backend="ray",
            progress=False,
        )
