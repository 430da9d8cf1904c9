"""Run files and the learning dataset: IO contract, resampling, row selection, windows,
masks, grouped split and training-only standardisation (synthetic toy runs, seconds)."""

from __future__ import annotations

import json
import math
import re
import shutil
import signal
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pytest

from killed_script import run_killed
from rmi_learn.cli import main as cli_main
from rmi_learn.data.dataset import (
    CATEGORICAL,
    Stats,
    build_dataset,
    compute_stats,
    grouped_split,
    load_dataset,
    resample_run,
    select_learning_rows,
)
from rmi_learn.data.runs import (
    RUN_COLUMNS,
    atomic_write_bytes,
    iter_run_files,
    read_run,
    read_run_meta,
    run_path,
    scan_runs,
    write_run,
)
from rmi_learn.data.schema import (
    ACTIONS,
    CONTINUOUS,
    CONTINUOUS_INDEX,
    CONTROL_ACTIONS,
    LEARNING_PHASES,
    OBS,
)
from rmi_learn.data.synthetic import simulate_toy_run
from rmi_learn.errors import InputError, RunFileError

torch = pytest.importorskip("torch")
torch.set_num_threads(1)

PARAMS = {"size_cm": 10, "porosity": 0.6, "F_hold": 90.0, "F_squeeze": 150.0, "seed": 0}


def toy(**kw: Any) -> dict[str, Any]:
    p = {**PARAMS, **kw}
    return simulate_toy_run(p["size_cm"], p["porosity"], p["F_hold"], p["F_squeeze"], p["seed"])


# --------------------------------------------------------------------------------------
# Run files


def test_run_file_roundtrip(tmp_path: Path) -> None:
    res = toy()
    path = run_path(tmp_path, PARAMS)
    write_run(path, res["columns"], res["config"], PARAMS, res["outcome"])
    df, meta = read_run(path)
    assert df.columns == list(RUN_COLUMNS)
    assert df.schema["phase"] == pl.String and df.schema["gate_open"] == pl.Boolean
    assert all(df.schema[c] == pl.Float64 for c in RUN_COLUMNS if c not in ("phase", "gate_open"))
    for name in RUN_COLUMNS:
        a, b = df[name].to_numpy(), np.asarray(res["columns"][name])
        if a.dtype.kind == "f":
            np.testing.assert_array_equal(a, b.astype(np.float64))  # NaN == NaN here
        else:
            assert (a == b).all(), name
    assert meta["params"] == PARAMS
    assert meta["config"] == json.loads(json.dumps(res["config"]))
    assert meta["outcome"]["lift_success"] is True
    assert meta["outcome"]["water_removed"]["ramp"] > 0
    assert meta["version"] and meta["git"]
    # Metadata alone, without the data, and the raw Parquet keys of the contract.
    assert read_run_meta(path) == meta
    raw = pl.read_parquet_metadata(path)
    assert {"rmi.config", "rmi.params", "rmi.outcome", "rmi.version", "rmi.git"} <= set(raw)
    assert path.relative_to(tmp_path).as_posix() == (
        "size_cm=10/porosity=0.6/F_hold=90/F_squeeze=150/seed=0/run.parquet"
    )
    assert [p.name for p in path.parent.iterdir()] == ["run.parquet"]  # no temporaries


def test_a_damaged_run_file_is_named_not_a_polars_error(tmp_path: Path) -> None:
    # A run file cut short (a full disk, an interrupted copy) is a RunFileError naming the
    # file and saying how to get the run back; the dataset command reports it in one line.
    res = toy()
    path = run_path(tmp_path / "runs", PARAMS)
    write_run(path, res["columns"], res["config"], PARAMS, res["outcome"])
    path.write_bytes(path.read_bytes()[:2000])
    for read in (read_run, read_run_meta):
        with pytest.raises(RunFileError, match="unreadable run file.*delete it") as info:
            read(path)
        assert str(path) in str(info.value)
    with pytest.raises(RunFileError, match="unreadable"):
        build_dataset(tmp_path / "runs", tmp_path / "ds")
    assert not (tmp_path / "ds").exists()


def test_write_run_refuses_nan_outside_v_res(tmp_path: Path) -> None:
    res = toy()
    cols = dict(res["columns"])
    assert np.isnan(cols["v_res"]).any()  # NaN before contact is allowed
    bad = cols["F_meas"].copy()
    bad[7] = np.nan
    path = tmp_path / "r" / "run.parquet"
    with pytest.raises(RunFileError, match="'F_meas'.*row 7"):
        write_run(path, {**cols, "F_meas": bad}, {}, PARAMS, {})
    inf = cols["M_L"].copy()
    inf[0] = np.inf
    with pytest.raises(RunFileError, match="'M_L'"):
        write_run(path, {**cols, "M_L": inf}, {}, PARAMS, {})
    with pytest.raises(RunFileError, match="missing.*'S'"):
        write_run(path, {k: v for k, v in cols.items() if k != "S"}, {}, PARAMS, {})
    with pytest.raises(RunFileError, match="unknown.*'extra'"):
        write_run(path, {**cols, "extra": cols["S"]}, {}, PARAMS, {})
    with pytest.raises(RunFileError, match="'w' has"):
        write_run(path, {**cols, "w": cols["w"][:-1]}, {}, PARAMS, {})
    assert not path.parent.exists() or not any(path.parent.iterdir())


def test_atomic_write_leaves_nothing_on_failure(tmp_path: Path) -> None:
    target = tmp_path / "x.parquet"
    target.write_bytes(b"old")

    def boom(f: Any) -> None:
        f.write(b"partial")
        raise RuntimeError("killed")

    with pytest.raises(RuntimeError):
        atomic_write_bytes(target, boom)
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.parquet"]


def test_scan_runs_gives_typed_partitions(synthetic_runs_dir: Path) -> None:
    lf = scan_runs(synthetic_runs_dir)
    per_run = (
        lf.group_by("size_cm", "porosity", "F_hold", "F_squeeze")
        .agg(pl.col("M_L").first().alias("m0"), pl.len().alias("n"))
        .collect()
    )
    assert per_run.height == len(list(iter_run_files(synthetic_runs_dir)))
    assert per_run.schema["size_cm"] == pl.Int64 and per_run.schema["F_hold"] == pl.Float64
    assert set(per_run["size_cm"].to_list()) == {8, 10, 12}


# --------------------------------------------------------------------------------------
# Resampling and row selection


def frame(time: np.ndarray, **cols: Any) -> pl.DataFrame:
    n = time.size
    data: dict[str, Any] = {"time": time, "phase": cols.pop("phase", ["hold"] * n)}
    for name in OBS + ACTIONS:
        data[name] = cols.pop(name, np.zeros(n))
    assert not cols
    return pl.DataFrame(data)


def test_resample_interpolates_continuous_and_holds_categorical() -> None:
    # Records every 5 ms, offset by 2.5 ms so that no record falls on the 20 ms grid.
    t = 0.0025 + 0.005 * np.arange(200)
    lin = 3.0 * t + 1.0
    sine = np.sin(2 * np.pi * 1.5 * t)
    c = (t >= 0.3124).astype(float)  # switches between records 0.3125 and 0.3075
    vres = np.where(c > 0, 0.01, np.nan)
    phase = np.where(t < 0.5125, "close", "ramp")
    out = resample_run(frame(t, M_L=lin, F_meas=sine, c=c, v_res=vres, phase=phase))
    grid = out["time"]
    assert np.allclose(np.diff(grid), 0.02) and grid[0] == pytest.approx(0.02)
    assert grid[-1] <= t[-1] and t[-1] - grid[-1] < 0.02
    np.testing.assert_allclose(out["k"] * 0.02, grid)
    np.testing.assert_allclose(out["M_L"], 3.0 * grid + 1.0, rtol=0, atol=1e-12)
    # Linear interpolation of a smooth signal: error <= h^2/8 max|f''| with h = 5 ms.
    bound = 0.005**2 / 8 * (2 * np.pi * 1.5) ** 2
    assert np.max(np.abs(out["F_meas"] - np.sin(2 * np.pi * 1.5 * grid))) <= bound
    # Categorical: the last record at or before the grid time (0.32 -> record 0.3175: 1).
    expect_c = (grid >= 0.3124).astype(float)
    np.testing.assert_array_equal(out["c"], expect_c)
    assert set(np.unique(out["c"])) <= {0.0, 1.0}
    np.testing.assert_array_equal(out["phase"], np.where(grid < 0.5125, "close", "ramp"))
    # v_res: NaN unless both bracketing records are finite.
    assert np.isnan(out["v_res"][grid < 0.31]).all()
    assert np.all(out["v_res"][grid > 0.32] == pytest.approx(0.01))


def test_resample_on_grid_records_is_exact() -> None:
    t = 0.005 * np.arange(100)  # records on the grid every 4th row
    x = np.random.default_rng(0).standard_normal(100)
    out = resample_run(frame(t, S=x, r_slip=(x > 0).astype(float)))
    np.testing.assert_array_equal(out["S"], x[::4])
    np.testing.assert_array_equal(out["r_slip"], (x[::4] > 0).astype(float))


def test_select_learning_rows_drops_excluded_phases_and_first_close() -> None:
    phase = np.array(
        [
            "settle",
            "settle",
            "close",
            "close",
            "close",
            "ramp",
            "hold",
            "lift",
            "waiting",
            "waiting",
            "squeeze",
            "done",
        ]
    )
    keep = select_learning_rows(phase)
    assert phase[keep].tolist() == ["close", "close", "ramp", "hold", "lift", "squeeze"]
    assert not keep[2] and keep[3]


def test_dataset_rows_come_from_learning_phases(
    synthetic_dataset_dir: Path, synthetic_runs_dir: Path
) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    phases = set(ds.frames["phase"].unique().to_list())
    assert phases <= set(LEARNING_PHASES) and "waiting" not in phases
    assert {"close", "ramp", "hold", "lift", "squeeze"} == phases
    # Per run: the first close grid row is gone, the second is kept, and every kept row
    # equals the resampled run file.
    for run in range(ds.runs.height):
        rid = ds.run_ids[run]
        df, _ = read_run(synthetic_runs_dir / rid / "run.parquet")
        grid = resample_run(df)
        close_k = grid["k"][grid["phase"] == "close"]
        rows = ds.frames.filter(pl.col("run") == run)
        ks = rows["k"].to_numpy()
        assert close_k[0] not in ks and close_k[1] in ks
        assert rows["t"].to_list() == list(range(rows.height))
        sel = np.isin(grid["k"], ks)
        np.testing.assert_array_equal(rows["M_L"].to_numpy(), grid["M_L"][sel])
        assert (np.diff(ks) >= 1).all()


# --------------------------------------------------------------------------------------
# Windows


def test_windows_stride_one_never_cross_runs_or_gaps(synthetic_dataset_dir: Path) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    L, H = 16, 64
    k = ds.frames["k"].to_numpy()
    total = 0
    for split in ("train", "val", "test"):
        ws = ds.windows(split)
        total += len(ws)
        anchors = ws.anchors
        span = anchors[:, None] + np.arange(-L + 1, H + 1)
        # One run and consecutive grid times across the whole window.
        assert (ds.row_run[span] == ds.row_run[anchors][:, None]).all()
        assert (np.diff(k[span], axis=1) == 1).all()
        runs = set(ds.split_runs(split).tolist())
        assert set(ds.row_run[anchors].tolist()) <= runs
    # Stride 1: every contiguous segment of n rows yields exactly n - L - H + 1 windows.
    seg_len = ds.frames.group_by("segment").len()["len"].to_numpy()
    assert total == int(np.clip(seg_len - L - H + 1, 0, None).sum())
    assert total > 0
    # The gap left by the waiting phase splits runs into two segments.
    assert (ds.runs["n_segments"] == 2).all()


def test_window_contents(synthetic_dataset_dir: Path) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    ws = ds.windows("train", size_cm=10)
    assert len(ws) > 0 and set(ds.runs.filter(pl.col("split") == "train")["size_cm"]) >= {10}
    item = ws[5]
    assert item["hist"].shape == (16, 23) and item["hist"].dtype == torch.float32
    assert item["actions"].shape == (64, 1) and item["target"].shape == (64, 18)
    assert item["target_r"].dtype == torch.int64 and item["target_c"].shape == (64,)
    assert item["water_now"].shape == ()
    run, t = int(item["run"]), int(item["t"])
    rows = ds.frames.filter(pl.col("run") == run).sort("t")
    assert int(ds.runs.filter(pl.col("run") == run)["size_cm"][0]) == 10
    z = rows.select(CONTINUOUS).to_numpy()
    u = rows.select(CONTROL_ACTIONS).to_numpy()
    # target = standardised z at t+1..t+H; actions = standardised u at t..t+H-1 (compared in
    # standardised units: float32 carries ~1e-7 of a channel's spread).
    zs, us = ds.stats.standardise_z(z), ds.stats.standardise_u(u)
    ok = item["target_mask"].numpy() > 0
    np.testing.assert_allclose(item["target"].numpy()[ok], zs[t + 1 : t + 65][ok], atol=1e-5)
    np.testing.assert_allclose(item["actions"].numpy(), us[t : t + 64], atol=1e-5)
    hm = item["hist_mask"][:, list(CONTINUOUS_INDEX)].numpy() > 0
    hist_z = item["hist"][:, list(CONTINUOUS_INDEX)].numpy()
    np.testing.assert_allclose(hist_z[hm], zs[t - 15 : t + 1][hm], atol=1e-5)
    assert item["water_now"].item() == pytest.approx(zs[t, 0], abs=1e-5)
    # Back to SI units.
    back = ds.stats.destandardise_z(item["target"].double()).numpy()
    np.testing.assert_allclose(back[:, 0], z[t + 1 : t + 65, 0], rtol=1e-5)
    onehot = rows.select(["r_none", "r_stick", "r_slip", "r_mixed"]).to_numpy()[t + 1 : t + 65]
    assert (item["target_r"].numpy() == onehot.argmax(1)).all()
    assert (item["target_c"].numpy() == rows["c"].to_numpy()[t + 1 : t + 65]).all()
    # batch == stacked items
    b = ws.batch([5, 0, len(ws) - 1])
    for key, v in item.items():
        assert torch.equal(b[key][0], v), key
    assert b["hist"].shape == (3, 16, 23)
    with pytest.raises(IndexError):
        ws[len(ws)]


def test_masks_only_v_res_and_physical_zeros_valid(synthetic_dataset_dir: Path) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    raw = ds.frames.select(OBS).to_numpy()
    vres = OBS.index("v_res")
    nan = np.isnan(raw)
    assert nan[:, vres].any() and not np.delete(nan, vres, axis=1).any()
    # The dataset mask equals finiteness, channel by channel.
    np.testing.assert_array_equal(ds.y_mask, (~nan).astype(np.float32))
    # Windows that include no-contact rows: v_res masked there, A_L = 0 stays valid.
    ws = ds.windows(None, history=16, horizon=64)
    b = ws.batch(np.arange(len(ws)))
    c_hist = b["hist"][..., OBS.index("c")]
    no_contact = c_hist == 0
    assert no_contact.any()
    assert (b["hist_mask"][..., vres][no_contact] == 0).all()
    assert (b["hist"][..., vres][no_contact] == 0).all()  # invalid -> 0
    a_l = OBS.index("A_L")
    assert (b["hist_mask"][..., a_l] == 1).all()
    zero_area = b["hist"][..., a_l][no_contact]
    expect = torch.tensor(
        ds.stats.standardise_z(np.zeros(18))[CONTINUOUS.index("A_L")], dtype=torch.float32
    )
    assert torch.allclose(zero_area, expect.expand_as(zero_area))  # standardised physical zero
    # Categorical channels stay raw 0/1.
    cat = [OBS.index(n) for n in CATEGORICAL]
    assert set(torch.unique(b["hist"][..., cat]).tolist()) <= {0.0, 1.0}
    # target mask: v_res is the only continuous channel ever masked.
    tm = b["target_mask"]
    assert (tm[..., [i for i in range(18) if CONTINUOUS[i] != "v_res"]] == 1).all()


# --------------------------------------------------------------------------------------
# Split and statistics


def test_grouped_split_on_the_paper_grid() -> None:
    rows = [
        {"size_cm": s, "porosity": p, "F_hold": float(fh), "F_squeeze": float(fs), "seed": 0}
        for s in (8, 10, 12)
        for p in (0.5, 0.6, 0.7)
        for fh in range(10, 211, 20)
        for fs in range(50, 301, 50)
    ]
    # Drop some runs (as unstable ones would be) so groups have different sizes.
    rng = np.random.default_rng(3)
    rows = [r for r in rows if rng.random() > 0.3]
    params = pl.DataFrame(rows)
    split = grouped_split(params, seed=0)
    df = params.with_columns(pl.Series("split", split))
    groups = df.group_by("size_cm", "porosity", "F_hold").agg(pl.col("split").n_unique())
    assert (groups["split"] == 1).all()  # every group on one side
    for s in (8, 10, 12):
        g = df.filter(pl.col("size_cm") == s).unique(["porosity", "F_hold", "split"])
        counts = g.group_by("split").len().sort("split")
        assert dict(zip(counts["split"], counts["len"], strict=True)) == {
            "train": 23,
            "val": 3,
            "test": 7,
        }
        runs = df.filter(pl.col("size_cm") == s)["split"].value_counts(normalize=True)
        frac = dict(zip(runs["split"], runs["proportion"], strict=True))
        assert frac["train"] == pytest.approx(0.7, abs=0.1)
        assert frac["val"] == pytest.approx(0.1, abs=0.06)
        assert frac["test"] == pytest.approx(0.2, abs=0.08)
    # Deterministic, row-order independent, seed-dependent.
    assert grouped_split(params, seed=0) == split
    rev = params.reverse()
    assert grouped_split(rev, seed=0) == split[::-1]
    assert grouped_split(params, seed=1) != split


def test_dataset_keeps_only_stable_runs(
    synthetic_dataset_dir: Path, synthetic_runs_dir: Path
) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    expected = set()
    for path in iter_run_files(synthetic_runs_dir):
        meta = read_run_meta(path)
        if meta["outcome"]["lift_success"] and meta["outcome"]["stable_squeeze"]:
            expected.add(path.parent.relative_to(synthetic_runs_dir).as_posix())
    assert set(ds.run_ids) == expected
    counts = ds.info["counts"]
    assert counts["lift_failed"] > 0 and counts["squeeze_unstable"] > 0
    assert counts["kept"] == len(expected)
    groups = ds.runs.group_by("size_cm", "porosity", "F_hold").agg(pl.col("split").n_unique())
    assert (groups["split"] == 1).all()
    for s in (8, 10, 12):
        assert set(ds.runs.filter(pl.col("size_cm") == s)["split"]) == {"train", "val", "test"}


def test_stats_from_training_split_only(
    synthetic_dataset_dir: Path, synthetic_runs_dir: Path, tmp_path: Path
) -> None:
    ds = load_dataset(synthetic_dataset_dir)
    train = ds.frames.filter(pl.col("run").is_in(ds.split_runs("train").tolist()))
    z = train.select(CONTINUOUS).to_numpy()
    np.testing.assert_allclose(ds.stats.z_mean, np.nanmean(z, axis=0), rtol=1e-10)
    std = np.nanstd(z, axis=0)
    np.testing.assert_allclose(ds.stats.z_std, np.where(std > 0, std, 1.0), rtol=1e-10)
    u = train.select(CONTROL_ACTIONS).to_numpy()
    np.testing.assert_allclose(ds.stats.u_mean, u.mean(0), rtol=1e-10)
    # By construction: perturb one test-split run and one validation run, rebuild, statistics
    # are identical; perturbing a training run changes them (the check has power).
    runs = tmp_path / "runs"
    shutil.copytree(synthetic_runs_dir, runs)

    def perturb(run_id: str) -> None:
        path = runs / run_id / "run.parquet"
        df, meta = read_run(path)
        cols = {c: df[c].to_numpy() for c in df.columns}
        cols["M_L"] = cols["M_L"] * 10.0 + 1.0
        cols["F_target"] = cols["F_target"] + 100.0
        write_run(path, cols, meta["config"], meta["params"], meta["outcome"])

    for split in ("test", "val"):
        perturb(ds.runs.filter(pl.col("split") == split)["run_id"][0])
    other = load_dataset(build_dataset(runs, tmp_path / "ds1"))
    assert other.runs["split"].to_list() == ds.runs["split"].to_list()
    for a in ("z_mean", "z_std", "u_mean", "u_std"):
        np.testing.assert_array_equal(getattr(other.stats, a), getattr(ds.stats, a))
    assert not np.array_equal(other.frames["M_L"].to_numpy(), ds.frames["M_L"].to_numpy())
    perturb(ds.runs.filter(pl.col("split") == "train")["run_id"][0])
    moved = load_dataset(build_dataset(runs, tmp_path / "ds2"))
    assert moved.stats.z_mean[0] != ds.stats.z_mean[0]
    assert moved.stats.u_mean[0] != ds.stats.u_mean[0]


def test_stats_roundtrip_numpy_and_torch() -> None:
    rng = np.random.default_rng(0)
    z = rng.standard_normal((50, 18)) * 3 + 2
    z[:, 5] = 4.0  # constant channel -> divisor 1
    z[::3, 17] = np.nan
    st = compute_stats(z, rng.standard_normal((50, 1)))
    assert st.z_std[5] == 1.0 and math.isfinite(st.z_mean[17])
    x = rng.standard_normal((4, 7, 18))
    np.testing.assert_allclose(st.destandardise_z(st.standardise_z(x)), x)
    tx = torch.tensor(x, dtype=torch.float32)
    back = st.destandardise_z(tx)
    assert isinstance(back, torch.Tensor) and back.dtype == torch.float32
    np.testing.assert_allclose(back.numpy(), st.destandardise_z(x), rtol=1e-5, atol=1e-5)
    u = torch.zeros(3, 1, dtype=torch.float64)
    np.testing.assert_allclose(st.destandardise_u(u).numpy(), np.tile(st.u_mean, (3, 1)))
    assert Stats.from_json(json.loads(json.dumps(st.to_json()))).z_std.tolist() == st.z_std.tolist()


@pytest.mark.parametrize(
    ("field", "value", "says"),
    [
        ("z_std", 0.0, "statistics field 'z_std' must be finite and > 0"),
        ("u_std", -1.0, "statistics field 'u_std' must be finite and > 0"),
        ("z_mean", float("nan"), "statistics field 'z_mean' must be finite"),
        ("u_mean", float("inf"), "statistics field 'u_mean' must be finite"),
        ("z_mean", "x", "could not convert"),
        ("u_std", None, "statistics field 'u_std' is missing"),
    ],
)
def test_statistics_that_would_standardise_to_nan_are_named(
    synthetic_dataset_dir: Path, tmp_path: Path, field: str, value: Any, says: str
) -> None:
    """A hand-edited ``stats.json`` whose standardisation would divide by zero or shift by
    NaN (and so train on NaN) is refused when the dataset is opened, naming the file."""
    data = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, data)
    stats = json.loads((data / "stats.json").read_text())
    if value is None:
        del stats[field]
    else:
        stats[field][0] = value
    (data / "stats.json").write_text(json.dumps(stats))
    with pytest.raises(InputError, match=re.escape(says)) as err:
        load_dataset(data)
    assert str(err.value).startswith(f"{data / 'stats.json'}: ")


# --------------------------------------------------------------------------------------
# CLI


def test_cli_build_and_info(
    synthetic_runs_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "ds"
    assert cli_main(["dataset", "build", "--runs", str(synthetic_runs_dir), "--out", str(out)]) == 0
    assert (out / "dataset.json").exists() and (out / "frames.parquet").exists()
    assert cli_main(["dataset", "info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "train/10cm" in text and "windows" in text
    assert (
        cli_main(["dataset", "--runs", str(tmp_path / "none"), "--out", str(tmp_path / "x")]) == 2
    )
    with pytest.raises(FileNotFoundError):
        load_dataset(tmp_path / "x")


def test_a_killed_build_leaves_the_previous_dataset_and_its_temporary_goes_next_time(
    synthetic_runs_dir: Path, synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    """A build killed with SIGKILL just before it moves its files in leaves the dataset that
    was in --out as it was, and the next build into --out removes its temporary directory."""
    out = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    script = (
        "import os, signal, sys\n"
        "from rmi_learn.data import staging\n"
        "from rmi_learn.data.dataset import build_dataset\n"
        "staging.move_in = lambda *a: os.kill(os.getpid(), signal.SIGKILL)\n"
        "build_dataset(sys.argv[1], sys.argv[2], seed=1)\n"
    )
    killed = run_killed(script, str(synthetic_runs_dir), str(out))
    assert killed.returncode == -signal.SIGKILL
    hidden = [p for p in out.iterdir() if p.name.startswith(".build.")]
    assert len(hidden) == 1 and (hidden[0] / "dataset.json").is_file()
    assert {p.name: p.read_bytes() for p in out.iterdir() if p not in hidden} == before
    assert cli_main(["dataset", "build", "--runs", str(synthetic_runs_dir), "--out", str(out)]) == 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # the same build again


@pytest.mark.parametrize("seed", [-1, 2**63, True])
def test_a_split_seed_out_of_the_range_is_refused_before_anything_is_written(
    tmp_path: Path, synthetic_runs_dir: Path, seed: object
) -> None:
    out = tmp_path / "ds"
    with pytest.raises(ValueError, match=r"seed must be an integer in \[0, 9223372036854775807\]"):
        build_dataset(synthetic_runs_dir, out, seed=seed)  # type: ignore[arg-type]
    assert not out.exists()
