"""The sweep driver: resumable idempotent runs, failures, kill -9 recovery, the index, the
``rmi sweep`` command and the Ray backend on a Ray started here.

The engine's ``rmi_sph.run_trial`` is replaced by the test doubles of ``sweep_doubles``. An
end-to-end test with the real engine is ``test_sweep_engine.py``.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from sweep_doubles import (
    FAIL_HOLD,
    UNSTABLE_SQUEEZE,
    fake_make_config,
    fake_runner,
    grid,
    logged,
)

import rmi_learn.data.sweep.index as index
from rmi_learn.cli import main as cli_main
from rmi_learn.data.runs import iter_run_files, read_run, run_path, scan_runs
from rmi_learn.data.sweep.grid import RunSpec, expand_grid, load_grid
from rmi_learn.data.sweep.index import INDEX_FILE, RUNS_SUBDIR, build_index
from rmi_learn.data.sweep.run import estimate_wall_time, longest_first, run_sweep

TESTS = Path(__file__).resolve().parent


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


def test_a_runner_hook_that_cannot_be_loaded_is_a_usage_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    gfile = tmp_path / "g.json"
    gfile.write_text(json.dumps(grid(sizes_cm=[8], porosities=[0.5], hold_forces_N=[150])))
    argv = ["sweep", "--grid", str(gfile), "--out", str(tmp_path / "s"), "--workers", "0"]
    with pytest.raises(SystemExit) as info:
        cli_main([*argv, "--runner", "rmi_sph:no_such_runner"])
    assert info.value.code == 2 and "no_such_runner" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


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
        "sweep_doubles:fake_runner",
        "--make-config",
        "sweep_doubles:fake_make_config",
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


class _FullDisk:
    """A file on a full disk: every write fails with ENOSPC."""

    def write(self, data: object) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_an_index_on_a_full_disk_is_one_line_and_keeps_the_old_index(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    specs = expand_grid(grid(sizes_cm=[8], hold_forces_N=[30, 150]))
    run_sweep(specs, out, runner=fake_runner, make_config=fake_make_config, workers=0,
              progress=False)  # fmt: skip
    before = (out / INDEX_FILE).read_bytes()
    real = index.atomic_write_bytes
    monkeypatch.setattr(
        index, "atomic_write_bytes", lambda path, writer: real(path, lambda f: writer(_FullDisk()))
    )
    with pytest.raises(OSError) as err:
        build_index(out)
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(out / INDEX_FILE)
    capsys.readouterr()
    assert cli_main(["sweep", "--out", str(out), "--index-only"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rmi sweep: "), lines
    assert str(out / INDEX_FILE) in lines[0] and "No space left" in lines[0]
    assert (out / INDEX_FILE).read_bytes() == before
    assert not list(out.glob(".*.tmp"))


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
        "sweep_doubles:fake_runner",
        "--make-config",
        "sweep_doubles:fake_make_config",
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
