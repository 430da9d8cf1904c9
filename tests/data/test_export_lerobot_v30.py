"""``rmi dataset export --format lerobot`` in LeRobot's v3.0 layout (the default): packed data
files, the episode index that locates each episode in them, the task table and the schema
metadata LeRobot reads, per-episode statistics with quantiles, the frames equal to the v2.1
export's, and the refusals. With ``RMI_LEROBOT_PYTHON`` naming an interpreter that has
``lerobot`` installed (docs/data-contract.md), the export is also loaded by the real
``LeRobotDataset``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq
import pytest
from test_export_lerobot import check_columns, one_line, stats_of, vectors

from rmi_learn.cli import main
from rmi_learn.data import export_lerobot as lerobot
from rmi_learn.data.export_lerobot import layout_v30
from rmi_learn.data.export_lerobot.episodes import Episode
from rmi_learn.errors import InputError

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def exported(synthetic_dataset_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("lerobot30") / "export"
    argv = ["dataset", "export", "--format", "lerobot", "--data", str(synthetic_dataset_dir)]
    assert main([*argv, "--out", str(out)]) == 0
    return out


def test_layout_info_and_the_feature_types_in_the_schema(
    exported: Path, synthetic_dataset_dir: Path
) -> None:
    info = json.loads((exported / "meta" / "info.json").read_text())
    frames = pl.read_parquet(synthetic_dataset_dir / "frames.parquet")
    assert info["codebase_version"] == "v3.0" and info["fps"] == 50
    assert info["data_path"] == "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
    assert info["total_frames"] == frames.height and info["total_tasks"] == 1
    assert "total_chunks" not in info and info["data_files_size_in_mb"] == 100
    files = sorted(p.relative_to(exported).as_posix() for p in exported.rglob("*.parquet"))
    assert files == [
        "data/chunk-000/file-000.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/tasks.parquet",
    ]
    data = exported / "data" / "chunk-000" / "file-000.parquet"
    table = pl.read_parquet(data)
    assert table.columns == list(info["features"]) and table.height == frames.height
    check_columns(table, info["features"])
    hf = json.loads(pq.read_schema(data).metadata[b"huggingface"])["info"]["features"]
    assert hf["observation.state"] == {
        "feature": {"dtype": "float32", "_type": "Value"},
        "length": 23,
        "_type": "List",
    }
    assert hf["action"] == {"dtype": "float32", "_type": "Value"}


def test_the_episode_index_locates_every_episode_and_holds_its_statistics(
    exported: Path, synthetic_dataset_dir: Path
) -> None:
    info = json.loads((exported / "meta" / "info.json").read_text())
    table = pl.read_parquet(exported / "data")
    episodes = pl.read_parquet(exported / "meta" / "episodes")
    runs = pl.read_parquet(synthetic_dataset_dir / "runs.parquet")
    assert episodes["episode_index"].to_list() == list(range(info["total_episodes"]))
    assert episodes.height == runs.height
    split_of = dict(zip(runs["run_id"], runs["split"], strict=True))
    for ep in episodes.iter_rows(named=True):
        rows = table.slice(ep["dataset_from_index"], ep["length"])
        assert ep["dataset_to_index"] - ep["dataset_from_index"] == ep["length"]
        assert set(rows["episode_index"]) == {ep["episode_index"]}
        assert rows["index"].to_list() == list(range(ep["dataset_from_index"],
                                                     ep["dataset_to_index"]))  # fmt: skip
        assert ep["tasks"] == [lerobot.TASK] and split_of[ep["run_id"]] == ep["split"]
        assert (ep["data/chunk_index"], ep["data/file_index"]) == (0, 0)
        for name in ("observation.state", "action", "timestamp"):
            x = vectors(rows, name)
            want = stats_of(x)
            for key in ("mean", "std", "min", "max"):
                np.testing.assert_allclose(ep[f"stats/{name}/{key}"], want[key], rtol=1e-9,
                                           atol=1e-12)  # fmt: skip
            assert ep[f"stats/{name}/count"] == [rows.height]
            np.testing.assert_allclose(ep[f"stats/{name}/q90"], np.quantile(x, 0.9, axis=0))
    total = json.loads((exported / "meta" / "stats.json").read_text())
    np.testing.assert_allclose(
        total["observation.state"]["q50"], np.median(vectors(table, "observation.state"), axis=0)
    )
    assert total["action"]["count"] == [table.height]


def test_the_frames_are_those_of_the_v21_export(
    exported: Path, synthetic_dataset_dir: Path, tmp_path: Path
) -> None:
    old = lerobot.export_lerobot(synthetic_dataset_dir, tmp_path / "v21", "v2.1")
    v21 = pl.concat([pl.read_parquet(p) for p in sorted((old / "data").rglob("*.parquet"))])
    assert pl.read_parquet(exported / "data").equals(v21)


def test_the_task_text_is_the_index_of_the_task_table(exported: Path) -> None:
    path = exported / "meta" / "tasks.parquet"
    pandas = json.loads(pq.read_schema(path).metadata[b"pandas"])
    (index,) = pandas["index_columns"]
    table = pl.read_parquet(path)
    assert table[index].to_list() == [lerobot.TASK] and table["task_index"].to_list() == [0]


def test_episodes_fill_data_files_up_to_the_size_limit(
    synthetic_dataset_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    frame_bytes = 1000
    sizes = [600, 500, 1100, 10, 10]  # frames: 0.6, 0.5, 1.1, 0.01, 0.01 MB of 1 MB
    fake = [Episode(i, "r", "train", pl.DataFrame({"x": [0] * n}))
            for i, n in enumerate(sizes)]  # fmt: skip
    assert layout_v30.pack(fake, frame_bytes, limit_mb=1000 * 1000 / 1024**2) == [0, 1, 2, 3, 3]
    # A limit below one episode gives one file per episode, all found through the index.
    monkeypatch.setattr(layout_v30, "DATA_FILE_MB", 1e-6)
    out = lerobot.export_lerobot(synthetic_dataset_dir, tmp_path / "export")
    episodes = pl.read_parquet(out / "meta" / "episodes")
    for ep in episodes.iter_rows(named=True):
        path = out / "data" / f"chunk-000/file-{ep['data/file_index']:03d}.parquet"
        rows = pl.read_parquet(path)
        assert rows["index"].to_list() == list(range(ep["dataset_from_index"],
                                                     ep["dataset_to_index"]))  # fmt: skip
    assert episodes["data/file_index"].to_list() == list(range(episodes.height))


def test_without_pyarrow_the_v30_export_is_refused_in_one_line_and_v21_is_written(
    synthetic_dataset_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    argv = ["dataset", "export", "--data", str(synthetic_dataset_dir)]
    assert main([*argv, "--out", str(tmp_path / "v30")]) == 2
    assert "needs pyarrow" in one_line(capsys) and not (tmp_path / "v30").exists()
    assert main([*argv, "--codebase-version", "v2.1", "--out", str(tmp_path / "v21")]) == 0
    with pytest.raises(SystemExit) as bad:
        main([*argv, "--codebase-version", "v4.0", "--out", str(tmp_path / "v4")])
    assert bad.value.code == 2 and "--codebase-version" in capsys.readouterr().err
    with pytest.raises(InputError, match="--codebase-version must be one of v3.0, v2.1"):
        lerobot.export_lerobot(synthetic_dataset_dir, tmp_path / "v4", "3.0")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v21"]


LEROBOT_PYTHON = os.environ.get("RMI_LEROBOT_PYTHON")


@pytest.mark.skipif(
    not LEROBOT_PYTHON, reason="set RMI_LEROBOT_PYTHON to an interpreter with lerobot installed"
)
def test_the_real_lerobot_dataset_loads_the_export(exported: Path) -> None:
    """``LeRobotDataset`` opens the export without conversion, indexes it with
    ``delta_timestamps``, iterates a DataLoader epoch and reads the statistics."""
    assert LEROBOT_PYTHON is not None
    done = subprocess.run(
        [LEROBOT_PYTHON, str(HERE / "lerobot_client.py"), str(exported)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    info = json.loads((exported / "meta" / "info.json").read_text())
    assert got["frames"] == got["epoch_frames"] == info["total_frames"]
    assert got["episodes"] == info["total_episodes"]
    assert got["state"] == [3, 23] and got["action"] == [4]
    assert got["task"] == lerobot.TASK
    stats = json.loads((exported / "meta" / "stats.json").read_text())
    np.testing.assert_allclose(got["action_mean"], stats["action"]["mean"], rtol=1e-6)
