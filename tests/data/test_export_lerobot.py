"""``rmi dataset export --format lerobot``: the LeRobot v2.1 layout read back with polars and
json (shapes, names, frame counts, timestamps, splits, statistics), action channels from the
dataset's metadata, and the refusals that leave nothing half-written. The v3.0 layout (the
default) is tested in ``test_export_lerobot_v30.py``."""

from __future__ import annotations

import json
import shutil
import signal
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pytest

from killed_script import run_killed
from rmi_learn.cli import main
from rmi_learn.data import export_lerobot as lerobot
from rmi_learn.data.schema import OBS, PHASES


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def vectors(table: pl.DataFrame, name: str) -> np.ndarray:
    """A feature's values as (frames, channels), a scalar column as one channel."""
    values = np.asarray(table[name].to_numpy(), dtype=np.float64)
    return values.reshape(table.height, -1)


def stats_of(values: np.ndarray) -> dict[str, list[float]]:
    """Population statistics recomputed here, independently of the exporter."""
    x = values.astype(np.float64).reshape(values.shape[0], -1)
    return {
        "mean": list(np.mean(x, axis=0)),
        "std": list(np.sqrt(np.mean((x - np.mean(x, axis=0)) ** 2, axis=0))),
        "min": list(np.min(x, axis=0)),
        "max": list(np.max(x, axis=0)),
        "count": [x.shape[0]],
    }


def assert_stats(got: dict[str, dict[str, list[float]]], table: pl.DataFrame) -> None:
    assert sorted(got) == sorted(table.columns)
    for name in table.columns:
        want = stats_of(vectors(table, name))
        for key in ("mean", "std", "min", "max"):
            np.testing.assert_allclose(got[name][key], want[key], rtol=1e-9, atol=1e-12)
        assert got[name]["count"] == want["count"]


def check_columns(table: pl.DataFrame, feats: dict[str, dict[str, Any]]) -> None:
    """Vectors are fixed-size float32 lists; a feature of shape [1] (the one action here
    included) is a scalar column, as LeRobot stores it."""
    want = {"float32": pl.Float32, "int64": pl.Int64, "bool": pl.Boolean}
    for name, ft in feats.items():
        if ft["shape"] == [1]:
            assert table[name].dtype == want[ft["dtype"]], name
        else:
            assert table[name].dtype == pl.Array(pl.Float32, ft["shape"][0]), name


@pytest.fixture(scope="module")
def exported(synthetic_dataset_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("lerobot") / "export"
    argv = ["dataset", "export", "--format", "lerobot", "--codebase-version", "v2.1"]
    argv += ["--data", str(synthetic_dataset_dir)]
    assert main([*argv, "--out", str(out)]) == 0
    return out


def test_layout_and_info(exported: Path, synthetic_dataset_dir: Path) -> None:
    info = json.loads((exported / "meta" / "info.json").read_text())
    frames = pl.read_parquet(synthetic_dataset_dir / "frames.parquet")
    runs = pl.read_parquet(synthetic_dataset_dir / "runs.parquet")
    assert info["codebase_version"] == "v2.1"
    assert info["fps"] == 50 and info["chunks_size"] == 1000 and info["total_chunks"] == 1
    assert info["total_episodes"] == runs.height
    assert info["total_frames"] == frames.height
    assert info["total_tasks"] == 1
    feats = info["features"]
    assert feats["observation.state"]["shape"] == [23]
    assert feats["observation.state"]["names"] == list(OBS)
    assert feats["action"]["names"] == ["F_target"]
    assert feats["action"]["shape"] == [1]
    tasks = read_jsonl(exported / "meta" / "tasks.jsonl")
    assert tasks == [{"task_index": 0, "task": lerobot.TASK}]
    files = sorted((exported / "data").rglob("*.parquet"))
    assert len(files) == runs.height
    for ep in range(runs.height):
        path = exported / info["data_path"].format(episode_chunk=0, episode_index=ep)
        assert path in files
        table = pl.read_parquet(path)
        assert table.columns == list(feats)
        check_columns(table, feats)


def test_episodes_are_the_runs_with_their_frames_and_split(
    exported: Path, synthetic_dataset_dir: Path
) -> None:
    info = json.loads((exported / "meta" / "info.json").read_text())
    frames = pl.read_parquet(synthetic_dataset_dir / "frames.parquet")
    runs = pl.read_parquet(synthetic_dataset_dir / "runs.parquet")
    episodes = read_jsonl(exported / "meta" / "episodes.jsonl")
    split_of = dict(zip(runs["run_id"], runs["split"], strict=True))
    run_of = dict(zip(runs["run_id"], runs["run"], strict=True))
    # Splits are contiguous episode ranges in train, val, test order.
    ranges = {s: range(*map(int, r.split(":"))) for s, r in info["splits"].items()}
    assert list(ranges) == ["train", "val", "test"]
    assert sum(len(r) for r in ranges.values()) == len(episodes)
    index = 0
    for ep in episodes:
        assert split_of[ep["run_id"]] == ep["split"]
        assert ep["episode_index"] in ranges[ep["split"]]
        assert ep["tasks"] == [lerobot.TASK]
        rows = frames.filter(pl.col("run") == run_of[ep["run_id"]]).sort("t")
        table = pl.read_parquet(
            exported / info["data_path"].format(episode_chunk=0, episode_index=ep["episode_index"])
        )
        n = table.height
        assert n == ep["length"] == rows.height
        assert table["frame_index"].to_list() == list(range(n))
        assert table["index"].to_list() == list(range(index, index + n))
        assert set(table["episode_index"]) == {ep["episode_index"]}
        assert table["next.done"].to_list() == [False] * (n - 1) + [True]
        np.testing.assert_allclose(np.diff(table["timestamp"].to_numpy()), 0.02, atol=1e-5)
        assert table["timestamp"][0] == 0.0
        np.testing.assert_allclose(table["sim_time"], rows["time"], rtol=1e-6)
        assert [PHASES[i] for i in table["phase_index"]] == rows["phase"].to_list()
        y = rows.select(OBS).to_numpy()
        state, mask = vectors(table, "observation.state"), vectors(table, "observation.state_mask")
        finite = np.isfinite(y)
        assert (mask == finite).all()
        assert (state[~finite] == 0.0).all()
        assert (state[finite] == y[finite].astype(np.float32)).all()
        u = rows.select("F_target").to_numpy().astype(np.float32)
        assert (vectors(table, "action") == u).all()
        index += n
    # The synthetic runs lose contact, so some v_res are NaN: the fill was exercised.
    assert frames["v_res"].is_nan().any()


def test_stats_equal_recomputed_values(exported: Path) -> None:
    info = json.loads((exported / "meta" / "info.json").read_text())
    tables = [pl.read_parquet(p) for p in sorted((exported / "data").rglob("*.parquet"))]
    per_episode = read_jsonl(exported / "meta" / "episodes_stats.jsonl")
    assert [e["episode_index"] for e in per_episode] == list(range(info["total_episodes"]))
    for rec in per_episode:
        table = next(t for t in tables if t["episode_index"][0] == rec["episode_index"])
        assert_stats(rec["stats"], table)
    assert_stats(json.loads((exported / "meta" / "stats.json").read_text()), pl.concat(tables))


def test_action_channels_come_from_the_dataset(synthetic_dataset_dir: Path, tmp_path: Path) -> None:
    data = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, data)
    stats = json.loads((data / "stats.json").read_text())
    assert stats["u_names"] == ["F_target"]
    stats["u_names"] = ["F_target", "v_cmd"]  # both recorded commands are in the frames
    (data / "stats.json").write_text(json.dumps(stats))
    out = lerobot.export_lerobot(data, tmp_path / "export", "v2.1")
    feats = json.loads((out / "meta" / "info.json").read_text())["features"]
    assert feats["action"] == {"dtype": "float32", "shape": [2], "names": ["F_target", "v_cmd"]}
    table = pl.read_parquet(next((out / "data").rglob("*.parquet")))
    assert vectors(table, "action").shape == (table.height, 2)


def one_line(capsys: pytest.CaptureFixture[str]) -> str:
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rmi dataset: "), lines
    return lines[0]


def test_refuses_a_non_empty_out_and_accepts_an_empty_one(
    synthetic_dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "export"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    argv = ["dataset", "export", "--data", str(synthetic_dataset_dir), "--out", str(out)]
    assert main(argv) == 2
    assert str(out) in one_line(capsys) and (out / "keep.txt").read_text() == "mine"
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    (out / "keep.txt").unlink()
    assert main(argv) == 0
    assert (out / "meta" / "info.json").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["export"]


def test_a_missing_action_channel_is_named(
    synthetic_dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, data)
    stats = json.loads((data / "stats.json").read_text())
    stats["u_names"] = ["F_target", "grip_speed"]
    (data / "stats.json").write_text(json.dumps(stats))
    out = tmp_path / "export"
    assert main(["dataset", "export", "--data", str(data), "--out", str(out)]) == 2
    line = one_line(capsys)
    assert "grip_speed" in line and str(data / "stats.json") in line
    assert not out.exists()


def test_a_failure_leaves_no_output_and_no_temporary(
    synthetic_dataset_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def boom(table: pl.DataFrame, quantiles: bool = False) -> dict[str, Any]:
        raise OSError("disk full")

    monkeypatch.setattr(lerobot.stats, "table_stats", boom)
    with pytest.raises(OSError, match="disk full"):
        lerobot.export_lerobot(synthetic_dataset_dir, tmp_path / "export")
    assert list(tmp_path.iterdir()) == []


def test_an_unknown_phase_is_named_with_the_accepted_names(
    synthetic_dataset_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A phase with no index in ``schema.PHASES`` once ended in a KeyError traceback."""
    data = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, data)
    frames = pl.read_parquet(data / "frames.parquet")
    phase = frames["phase"].to_list()
    phase[len(phase) // 2] = "wobble"
    frames.with_columns(pl.Series("phase", phase)).write_parquet(data / "frames.parquet")
    out = tmp_path / "export"
    assert main(["dataset", "export", "--data", str(data), "--out", str(out)]) == 2
    line = one_line(capsys)
    assert str(data / "frames.parquet") in line and "unknown phase 'wobble'" in line
    assert f"accepted: {', '.join(PHASES)}" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_the_temporary_of_a_killed_export_is_removed_by_the_next_one(
    synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    """An export killed with SIGKILL (here in the middle of its episodes) leaves its hidden
    temporary directory; the next export into the same directory removes it, and leaves
    any other hidden directory alone."""
    parent = tmp_path / "exports"
    parent.mkdir()
    (parent / ".notes.tmp").mkdir()  # not an export's: kept
    script = (
        "import os, signal, sys\n"
        "import rmi_learn.data.export_lerobot as lerobot\n"
        "lerobot.stats.table_stats = lambda *a, **k: os.kill(os.getpid(), signal.SIGKILL)\n"
        "lerobot.export_lerobot(sys.argv[1], sys.argv[2])\n"
    )
    killed = run_killed(script, str(synthetic_dataset_dir), str(parent / "first"))
    assert killed.returncode == -signal.SIGKILL
    left = [p.name for p in parent.iterdir() if p.name.startswith(".first.")]
    assert len(left) == 1 and (parent / left[0] / "data").is_dir()
    argv = ["dataset", "export", "--data", str(synthetic_dataset_dir)]
    assert main([*argv, "--out", str(parent / "second")]) == 0
    assert sorted(p.name for p in parent.iterdir()) == [".notes.tmp", "second"]


def test_an_out_linking_to_an_empty_directory_is_written_through(
    synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    """An empty --out is accepted, also as a symbolic link (once refused as "Not a
    directory"): the export lands where the link points, and the link stays."""
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    argv = ["dataset", "export", "--data", str(synthetic_dataset_dir), "--out", str(link)]
    assert main(argv) == 0
    assert link.is_symlink() and link.resolve() == real.resolve()
    info = json.loads((real / "meta" / "info.json").read_text())
    assert info["total_frames"] == pl.read_parquet(real / "data").height
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]
