"""``rmi closed-loop`` with the real engine: deterministic replay to a window's anchor,
execution of chunks through the external-action interface, resume and input errors.

One small real trial (8 cm sponge, r = 1 cm, dt = 2 ms, a slow lift and a long squeeze hold so
that both learning segments hold windows of 32 control steps) is simulated once per module.
The chunk files are written by hand from its recorded, resampled commands: ``original`` is the
recorded chunk, ``first`` scales its force targets by 1.5, ``selected`` equals ``original``.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pytest

import rmi_sph
from rmi_learn.cli import main
from rmi_learn.closed_loop import run_closed_loop
from rmi_learn.closed_loop.table import WINDOWS_FILE
from rmi_learn.data.runs import RUN_COLUMNS, read_run, write_run
from rmi_learn.data.schema import CONTROL_DT
from rmi_learn.data.sweep import RunSpec, run_sweep
from rmi_learn.sim.replay import RunTrack, check_anchor, load_track
from tiny_trial import TINY

PARAMS: dict[str, Any] = {
    "size_cm": 8,
    "porosity": 0.8,
    "F_hold": 20.0,
    "F_squeeze": 150.0,
    "seed": 0,
}
#: The tiny trial (tests/tiny_trial.py, its permeable foam included: the anchors below need
#: its timing) with a longer squeeze hold and a slower lift.
OVERRIDES: dict[str, Any] = {**TINY, "squeeze_hold_time": 0.6, "lift_speed": 0.06}
#: Anchors (kept-row index t): end of the hold (the lift gate opens inside the chunk), the
#: lift, the squeeze. The first two lie in the close..lift segment, the last is the first
#: kept row after waiting (checked by the fixture, so a change of the trial's timing names
#: itself instead of failing deep in a replay).
ANCHORS = (6, 14, 50)
H = 32
#: Columns that hold wall-clock times (the only values allowed to differ between runs).
WALL = ("wall_s", "replay_wall_s")


@pytest.fixture(scope="module")
def sweep_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sweep output with one real run (about 1.5 s of simulation)."""
    root = tmp_path_factory.mktemp("closed_loop") / "sweep"
    res = run_sweep([RunSpec(dict(PARAMS), 0.01, dict(OVERRIDES))], root, workers=0, progress=False)
    assert res.ok == 1
    k = _run(root)[2].k
    gap = int(np.flatnonzero(np.diff(k) != 1)[0]) + 1  # first kept row after waiting
    assert ANCHORS[1] + H < gap == ANCHORS[2] and ANCHORS[2] + H < k.size, (gap, k.size)
    return root


def _run(sweep: Path, i: int = 0) -> tuple[str, Path, RunTrack]:
    index = pl.read_parquet(sweep / "index.parquet").sort("run_id")
    path = sweep / index["path"][i]
    return str(index["run_id"][i]), path, load_track(path)


def write_chunks(
    out: Path,
    sweep: Path,
    anchors: Sequence[int] = ANCHORS,
    objective: str = "flow",
    h: int = H,
    nan_selected: Sequence[int] = (),
    goal_shift_kg: float = 0.0,
    run_id: str | None = None,
    runs: Sequence[int] = (0,),
) -> Path:
    """Write ``chunks_<objective>.npz`` as ``rmi rank`` does (float32 physical units), the
    windows at ``anchors`` of each of the sweep's ``runs`` (by position in run-id order)."""
    parts = [_chunks(sweep, anchors, h, nan_selected, goal_shift_kg, run_id, i) for i in runs]
    out.mkdir(parents=True, exist_ok=True)
    merged = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    np.savez_compressed(out / f"chunks_{objective}.npz", **merged)
    return out


def _chunks(
    sweep: Path,
    anchors: Sequence[int],
    h: int,
    nan_selected: Sequence[int],
    goal_shift_kg: float,
    run_id: str | None,
    i: int,
) -> dict[str, np.ndarray]:
    rid, _, track = _run(sweep, i)
    ts = np.asarray(anchors, dtype=np.int64)
    n = ts.size
    orig = np.stack([track.actions[t : t + h, :1] for t in ts]).astype(np.float32)
    first = orig.copy()
    first[..., 0] = np.minimum(first[..., 0] * 1.5, 400.0)
    selected = orig.copy()
    for i in nan_selected:
        selected[i, 5, 0] = np.nan
    j_m = np.tile(np.arange(8, dtype=np.float32) + 0.5, (n, 1))
    return dict(
        size_cm=np.full(n, PARAMS["size_cm"], dtype=np.int64),
        run=np.full(n, i, dtype=np.int64),
        t=ts,
        goal_kg=np.asarray([track.water[t + h] + goal_shift_kg for t in ts], dtype=np.float32),
        water_now_kg=np.asarray([track.water[t] for t in ts], dtype=np.float32),
        original=orig,
        first=first,
        selected=selected,
        index=np.full(n, 3, dtype=np.int64),
        J_samples=j_m,
        J_M_samples=j_m,
        run_id=np.asarray([run_id or rid] * n),
    )


def _no_nan_json(path: Path) -> Any:
    def refuse(name: str) -> None:
        raise AssertionError(f"{path} holds {name}")

    return json.loads(path.read_text(), parse_constant=refuse)


def _numbers(out: Path) -> pl.DataFrame:
    return (
        pl.read_parquet(out / WINDOWS_FILE)
        .drop(*WALL)
        .sort("run_id", "t", "objective", "chunk", nulls_last=True)
    )


def test_replay_to_the_anchor_reproduces_the_stored_record(sweep_dir: Path) -> None:
    rid, path, track = _run(sweep_dir)
    stored, meta = read_run(path)
    t = ANCHORS[1]
    k = int(track.k[t])
    sim = rmi_sph.Trial(meta["config"], num_threads=1, record=True)
    steps = round(k * CONTROL_DT / sim.dt)
    sim.step(steps)
    # The anchor's grid time is a record time of the run (records every 5 steps of 2 ms).
    assert abs(sim.time - k * CONTROL_DT) < 1e-9 and bool(track.exact[t])
    rows = sim.records()
    n = len(rows["time"])
    assert n == int((stored["time"].to_numpy() <= sim.time + 1e-9).sum())
    for name in RUN_COLUMNS:
        got, want = np.asarray(rows[name]), stored[name].to_numpy()[:n]
        if got.dtype.kind == "f":
            # Bit-identical, NaN (v_res without contact) in the same places.
            assert np.array_equal(got, want, equal_nan=True), name
        else:
            assert (got == want).all(), name
    # The command's own check (observation at the anchor against the resampled record).
    check_anchor(sim, track, rid, t)
    assert str(stored["phase"].to_numpy()[n - 1]) == str(track.phase[t]) == sim.phase


def test_executes_chunks_and_reproduces_the_original(sweep_dir: Path, tmp_path: Path) -> None:
    chunks = write_chunks(tmp_path / "rank", sweep_dir)
    # A second objective ranked two of the windows; its selected chunk of the first is broken.
    write_chunks(tmp_path / "rank", sweep_dir, (ANCHORS[0], ANCHORS[2]), "diffusion", H, [0])
    out = tmp_path / "cl"
    s = run_closed_loop(
        sweep_dir, chunks, out, max_windows=0, threads=1, command="force", progress=False
    )
    rows = pl.read_parquet(out / WINDOWS_FILE)
    assert rows.height == 3 * 3 + 2 * 2
    _, _, track = _run(sweep_dir)
    outcome = read_run(_run(sweep_dir)[1])[1]["outcome"]
    particle_kg = outcome["total_water"] / outcome["n_fluid"]
    orig = rows.filter(pl.col("chunk") == "original").sort("t")
    assert orig["t"].to_list() == list(ANCHORS)
    assert orig["goal_kg"].to_list() == [float(track.water[t + H]) for t in ANCHORS]
    assert (orig["status"] == "ok").all() and (orig["phase_end"] == orig["goal_phase"]).all()
    # Fidelity: the recorded targets held for 20 ms, with the engine's 1 ms force loop,
    # end within one fluid particle's mass of the collected M_L (the water the pores hold).
    # The only difference from the collected run is the zero-order hold of the (smoothly
    # ramping) force target, which shifts the load by a few N and the pore volume with it;
    # in the squeeze the water leaves with the load, so there the bound is two particles.
    for t, m, goal in zip(
        orig["t"].to_list(), orig["M_L_real_kg"].to_list(), orig["goal_kg"].to_list(), strict=True
    ):
        allowed = 2 if t == ANCHORS[2] else 1
        assert abs(m - goal) <= allowed * particle_kg + 1e-12, (t, m, goal)
    # first: 1.5 x the force target changes the outcome somewhere (force mode uses F_target).
    fl = rows.filter(pl.col("objective") == "flow").sort("t")
    first = fl.filter(pl.col("chunk") == "first")["M_L_real_kg"].to_list()
    sel = fl.filter(pl.col("chunk") == "selected")["M_L_real_kg"].to_list()
    # The selected chunk is the original commands as rmi rank stores them (float32), so its
    # outcome is the original's up to that rounding: a relative perturbation of about 6e-8 of
    # the force target, which moves where the implicit solve's CG stops by as much. Within a
    # thousandth of one particle's mass, the unit of the fidelity bounds above.
    np.testing.assert_allclose(sel, orig["M_L_real_kg"].to_list(), rtol=0, atol=1e-3 * particle_kg)
    assert first != sel
    # The broken chunk is recorded as such, with no value, and left out of the table.
    bad = rows.filter((pl.col("objective") == "diffusion") & (pl.col("chunk") == "selected"))
    assert bad.sort("t")["status"].to_list() == ["invalid_chunk", "ok"]
    assert bad.sort("t")["M_L_real_kg"].to_list()[0] is None
    assert not any(
        isinstance(v, float) and math.isnan(v) for c in rows.columns for v in rows[c].to_list()
    )
    e = s["sizes"]["8"]
    assert e["n_windows"] == 3 and e["original"]["n"] == 3
    assert e["flow"]["n"] == 3 and e["diffusion"]["n"] == 1 and e["diffusion"]["not_executed"] == 1
    fr = fl.filter(pl.col("chunk") == "first")["err_real_g"].to_list()
    assert e["flow"]["first_real_g"] == pytest.approx(np.mean(fr))
    assert e["flow"]["first_pred_g"] == pytest.approx(0.5) and e["flow"]["selected_pred_g"] == 3.5
    payload = _no_nan_json(out / "table_closed_loop.json")
    assert payload["sizes"]["8"]["flow"]["n"] == 3 and payload["command"] == "force"
    md = (out / "table_closed_loop.md").read_text()
    assert "| Original controller action (replayed at 20 ms) |" in md
    assert "| Flow matching + W_T |" in md and "Diffusion policy, first sample" in md
    # A ranking that names another scorer names the selected rows after it; the resumed call
    # executes nothing again.
    (tmp_path / "rank" / "table3_ranking.json").write_text(
        json.dumps({"scorer_name": "AC-GRU-WM", "rows": []})
    )
    s2 = run_closed_loop(
        sweep_dir, chunks, out, max_windows=0, threads=1, command="force", progress=False
    )
    assert s2["sizes"] == s["sizes"] and s2["windows_executed_now"] == 0
    assert s2["scorer_name"] == "AC-GRU-WM"
    md = (out / "table_closed_loop.md").read_text()
    assert "| Flow matching + AC-GRU-WM |" in md and "W_T" not in md


def test_runs_side_by_side_give_the_rows_of_one_run_at_a_time(
    sweep_dir: Path, tmp_path: Path
) -> None:
    """With two threads and two runs, the runs go to two processes of one engine thread."""
    two = tmp_path / "sweep"
    shutil.copytree(sweep_dir, two)
    spec = RunSpec({**PARAMS, "seed": 1}, 0.01, dict(OVERRIDES))
    assert run_sweep([spec], two, workers=0, progress=False).ok == 1
    chunks = write_chunks(tmp_path / "rank", two, anchors=ANCHORS[:2], h=8, runs=(0, 1))
    one = run_closed_loop(two, chunks, tmp_path / "one", max_windows=0, threads=1, progress=False)
    side = run_closed_loop(two, chunks, tmp_path / "two", max_windows=0, threads=2, progress=False)
    assert one["windows_executed_now"] == side["windows_executed_now"] == 4
    assert _numbers(tmp_path / "two").equals(_numbers(tmp_path / "one"))
    assert _numbers(tmp_path / "two")["run_id"].n_unique() == 2


def test_repeatable_and_resumes_without_redoing_windows(sweep_dir: Path, tmp_path: Path) -> None:
    h = 16  # shorter chunks keep this test fast; the code takes H from the npz
    chunks = write_chunks(tmp_path / "rank", sweep_dir, h=h)
    full = tmp_path / "full"
    a = run_closed_loop(sweep_dir, chunks, full, max_windows=0, threads=1, progress=False)
    assert a["windows_executed_now"] == 3 and a["chunk_steps"] == h
    # Same inputs in another directory, in two sittings (two windows, then all three) and
    # with two engine threads: identical numbers, and the second sitting runs one window.
    part = tmp_path / "part"
    b1 = run_closed_loop(sweep_dir, chunks, part, max_windows=2, threads=2, progress=False)
    assert b1["windows_executed_now"] == 2  # evenly spaced: the first and the last
    first_rows = _numbers(part)
    b2 = run_closed_loop(sweep_dir, chunks, part, max_windows=0, threads=2, progress=False)
    assert b2["windows_executed_now"] == 1
    assert _numbers(part).equals(_numbers(full))
    assert _numbers(part).filter(pl.col("t") != ANCHORS[1]).equals(first_rows)
    assert b2["sizes"] == a["sizes"]
    again = run_closed_loop(sweep_dir, chunks, part, max_windows=0, threads=1, progress=False)
    assert again["windows_executed_now"] == 0 and again["sizes"] == a["sizes"]
    args = ["closed-loop", "--runs", str(sweep_dir), "--chunks", str(chunks), "--out", str(part)]
    assert main([*args, "--max-windows", "0", "--no-progress"]) == 0  # nothing left to run
    assert _numbers(part).equals(_numbers(full))
    # Other chunk files are another experiment: the checkpoint is not mixed with them.
    other = write_chunks(tmp_path / "rank-other", sweep_dir, h=8)
    rc = main(
        ["closed-loop", "--runs", str(sweep_dir), "--chunks", str(other), "--out", str(part),
         "--no-progress"]
    )  # fmt: skip
    assert rc == 2


def _cli(
    capsys: pytest.CaptureFixture[str], sweep: Path, chunks: Path, out: Path
) -> tuple[int, str]:
    rc = main(
        ["closed-loop", "--runs", str(sweep), "--chunks", str(chunks), "--out", str(out),
         "--max-windows", "1", "--no-progress"]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return rc, err


def test_bad_inputs_exit_2_with_a_message(
    sweep_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "cl"
    (tmp_path / "empty").mkdir()
    rc, err = _cli(capsys, sweep_dir, tmp_path / "empty", out)
    assert rc == 2 and "no chunk file" in err
    rc, err = _cli(capsys, tmp_path / "nowhere", write_chunks(tmp_path / "r0", sweep_dir), out)
    assert rc == 2 and "index.parquet" in err

    other = "size_cm=8/porosity=0.5/F_hold=20/F_squeeze=150/seed=0"
    rc, err = _cli(capsys, sweep_dir, write_chunks(tmp_path / "r1", sweep_dir, run_id=other), out)
    assert rc == 2 and other in err

    shifted = write_chunks(tmp_path / "r2", sweep_dir, (ANCHORS[0],), goal_shift_kg=0.05)
    rc, err = _cli(capsys, sweep_dir, shifted, out)
    assert rc == 2 and "goal" in err and "another sweep" in err

    # An anchor whose 32 following rows cross the removed waiting phase is no ranked window.
    _, _, track = _run(sweep_dir)
    gap = int(np.flatnonzero(np.diff(track.k) != 1)[0])
    rc, err = _cli(capsys, sweep_dir, write_chunks(tmp_path / "r3", sweep_dir, (gap - 2,)), out)
    assert rc == 2 and "waiting" in err

    # A run file whose stored config is not the one that produced its rows: the replay
    # differs at the anchor and the command refuses to report anything.
    bad = tmp_path / "bad_sweep"
    shutil.copytree(sweep_dir, bad)
    rid, path, _ = _run(bad)
    frame, meta = read_run(path)
    config = dict(meta["config"], seed=7)
    write_run(path, frame.to_dict(as_series=False), config, meta["params"], meta["outcome"])
    chunks = write_chunks(tmp_path / "r4", sweep_dir, (ANCHORS[0],))
    rc, err = _cli(capsys, bad, chunks, tmp_path / "cl_bad")
    assert rc == 2 and "deterministic replay failed" in err and rid in err
    # A stored config this engine does not accept is refused before any simulation.
    write_run(path, frame.to_dict(as_series=False), {**config, "bogus": 1}, meta["params"], {})
    rc, err = _cli(capsys, bad, chunks, tmp_path / "cl_bad")
    assert rc == 2 and "refused by this engine" in err and "bogus" in err
    assert not (out / WINDOWS_FILE).exists()


def test_a_second_run_into_one_out_is_refused_naming_the_lock(
    sweep_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each run rewrites the whole checkpoint: while one writes ``--out`` (it holds the
    lock) another is refused with one line naming the lock, status 1 as for a locked sweep,
    and writes nothing; once the lock is free the same call runs."""
    fcntl = pytest.importorskip("fcntl")
    out = tmp_path / "cl"
    out.mkdir()
    chunks = write_chunks(tmp_path / "chunks", sweep_dir, (ANCHORS[0],))
    lock = out / ".closed-loop.lock"
    with open(lock, "a+b") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        rc, err = _cli(capsys, sweep_dir, chunks, out)
    assert rc == 1 and err.splitlines() == [
        f"rmi closed-loop: another closed-loop is writing {out} (lock {lock})"
    ]
    assert sorted(p.name for p in out.iterdir()) == [lock.name]
    rc, _ = _cli(capsys, sweep_dir, chunks, out)
    assert rc == 0 and (out / WINDOWS_FILE).exists()


def test_a_truncated_index_is_one_line(
    sweep_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "sweep"
    shutil.copytree(sweep_dir, bad)
    index = bad / "index.parquet"
    index.write_bytes(index.read_bytes()[: index.stat().st_size // 2])
    chunks = write_chunks(tmp_path / "chunks", sweep_dir, (ANCHORS[0],))
    rc, err = _cli(capsys, bad, chunks, tmp_path / "cl")
    lines = err.splitlines()
    assert rc == 2 and len(lines) == 1 and f"{index} is not readable" in lines[0], lines
    assert not (tmp_path / "cl").exists()
