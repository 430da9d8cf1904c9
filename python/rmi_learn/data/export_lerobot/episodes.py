"""The episodes of an export: the built dataset read and checked, one episode per run in
split order, and each episode's columns with the features ``info.json`` describes."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data.dataset import FORMAT_VERSION, SPLITS, read_table
from rmi_learn.data.schema import OBS, PHASES
from rmi_learn.errors import InputError

ROBOT_TYPE = "rmi_parallel_gripper"
TASK = "grasp, lift and squeeze the water-filled sponge"

#: Features of every episode, in column order after the vectors: (name, dtype).
_SCALARS: tuple[tuple[str, str], ...] = (
    ("sim_time", "float32"),
    ("phase_index", "int64"),
    ("next.done", "bool"),
    ("timestamp", "float32"),
    ("frame_index", "int64"),
    ("episode_index", "int64"),
    ("index", "int64"),
    ("task_index", "int64"),
)
_POLARS: Mapping[str, pl.DataType] = {
    "float32": pl.Float32(),
    "int64": pl.Int64(),
    "bool": pl.Boolean(),
}


def features(u_names: list[str]) -> dict[str, dict[str, Any]]:
    """The ``features`` entry of ``info.json`` for actions ``u_names``: dtype, shape and
    channel names of every column of an episode. A feature of shape [1] is a scalar column,
    as LeRobot stores it (one action channel included); longer ones are fixed-size lists."""
    out: dict[str, dict[str, Any]] = {
        "observation.state": {"dtype": "float32", "shape": [len(OBS)], "names": list(OBS)},
        "observation.state_mask": {"dtype": "float32", "shape": [len(OBS)], "names": list(OBS)},
        "action": {"dtype": "float32", "shape": [len(u_names)], "names": list(u_names)},
    }
    for name, dtype in _SCALARS:
        out[name] = {"dtype": dtype, "shape": [1], "names": None}
    return out


@dataclass(frozen=True)
class Source:
    """A built dataset ready to export: its directory and ``dataset.json``, the frame rate,
    the action channels and the runs as (run, run_id, split) in export order, with the kept
    rows of each run sorted by time."""

    data: Path
    info: dict[str, Any]
    fps: int
    u_names: list[str]
    runs: list[tuple[Any, ...]]
    rows: dict[int, pl.DataFrame]


def read_source(data: Path) -> Source:
    """Read and check the dataset built in ``data``: FileNotFoundError when it is not one,
    :class:`~rmi_learn.errors.InputError` naming the file for a damaged one, one without the
    named action channels or with a phase outside ``schema.PHASES``."""
    info_path = data / "dataset.json"
    if not info_path.is_file():
        raise FileNotFoundError(f"{data} is not a built dataset (no dataset.json)")
    info = json.loads(info_path.read_text(encoding="utf-8"))
    if not isinstance(info, dict) or info.get("format") != FORMAT_VERSION:
        raise InputError(f"{info_path}: not a dataset of format {FORMAT_VERSION}; rebuild it")
    fps = _fps(info, info_path)
    runs = read_table(data / "runs.parquet", ("run", "run_id", "split"))
    frames = read_table(data / "frames.parquet", ("run", "t", "time", "phase", *OBS))
    _check_phases(frames, data / "frames.parquet")
    u_names = _action_names(data / "stats.json", frames)
    order = {s: i for i, s in enumerate(SPLITS)}
    ordered = sorted(
        runs.select("run", "run_id", "split").rows(), key=lambda r: (order[r[2]], r[0])
    )
    rows = {int(key[0]): g.sort("t") for key, g in frames.group_by("run")}
    return Source(data, info, fps, u_names, ordered, rows)


def _action_names(path: Path, frames: pl.DataFrame) -> list[str]:
    """The dataset's action channels, from its ``stats.json``."""
    try:
        names = json.loads(path.read_text(encoding="utf-8")).get("u_names")
    except (json.JSONDecodeError, AttributeError) as exc:
        raise InputError(f"{path}: not the statistics of a built dataset ({exc})") from exc
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise InputError(f"{path}: 'u_names' must be a non-empty list of channel names")
    missing = [n for n in names if n not in frames.columns]
    if missing:
        raise InputError(f"{path}: action channel(s) {missing} are not columns of frames.parquet")
    return names


def _fps(info: dict[str, Any], path: Path) -> int:
    dt = info.get("dt")
    if not isinstance(dt, (int, float)) or not dt > 0:
        raise InputError(f"{path}: 'dt' must be a positive number of seconds, got {dt!r}")
    fps = round(1.0 / dt)
    if fps < 1 or not math.isclose(fps * dt, 1.0, rel_tol=1e-9):
        raise InputError(f"{path}: dt {dt} s is not a whole number of frames per second")
    return fps


def _check_phases(frames: pl.DataFrame, path: Path) -> None:
    """Refuse frames whose ``phase`` is not a name of ``schema.PHASES`` (it has no index)."""
    unknown = sorted(set(frames["phase"].unique().to_list()) - set(PHASES), key=str)
    if unknown:
        names = ", ".join(repr(p) for p in unknown)
        raise InputError(
            f"{path}: unknown phase {names} in column 'phase'; accepted: {', '.join(PHASES)}"
        )


def episode_table(
    rows: pl.DataFrame, source: Source, episode: int, first_index: int
) -> pl.DataFrame:
    """The frames of one run as an episode: the columns of :func:`features` in order."""
    n = rows.height
    y = rows.select(OBS).to_numpy().astype(np.float64)
    finite = np.isfinite(y)
    frame = np.arange(n, dtype=np.int64)
    phase = {p: i for i, p in enumerate(PHASES)}
    cols: dict[str, np.ndarray] = {
        "observation.state": np.where(finite, y, 0.0).astype(np.float32),
        "observation.state_mask": finite.astype(np.float32),
        "action": rows.select(source.u_names).to_numpy().astype(np.float32),
        "sim_time": rows["time"].to_numpy().astype(np.float32),
        "phase_index": np.array([phase[p] for p in rows["phase"].to_list()], dtype=np.int64),
        "next.done": frame == n - 1,
        "timestamp": (frame / source.fps).astype(np.float32),
        "frame_index": frame,
        "episode_index": np.full(n, episode, dtype=np.int64),
        "index": first_index + frame,
        "task_index": np.zeros(n, dtype=np.int64),
    }
    feats = features(source.u_names)
    series = []
    for name, arr in cols.items():
        dtype = _POLARS[feats[name]["dtype"]]
        width = feats[name]["shape"][0]
        if arr.ndim == 2 and width > 1:
            series.append(pl.Series(name, arr.astype(np.float32)).cast(pl.Array(dtype, width)))
        else:
            series.append(pl.Series(name, arr.reshape(n), dtype=dtype))
    return pl.DataFrame(series)


@dataclass(frozen=True)
class Episode:
    """One exported episode: its index, the run it comes from and that run's split, and its
    frames (:func:`episode_table`)."""

    index: int
    run_id: str
    split: str
    table: pl.DataFrame


def build_episodes(source: Source) -> list[Episode]:
    """Every run with kept rows as an episode, numbered in export order with a global frame
    index; InputError when no run has any."""
    out: list[Episode] = []
    total = 0
    for run, run_id, split in source.runs:
        rows = source.rows.get(int(run))
        if rows is None or rows.height == 0:
            continue  # a run without kept rows has no frames to export
        table = episode_table(rows, source, len(out), total)
        out.append(Episode(len(out), str(run_id), str(split), table))
        total += table.height
    if not out:
        raise InputError(f"{source.data}: the dataset has no frames to export")
    return out


def split_bounds(episodes: list[Episode]) -> dict[str, str]:
    """``info.json``'s ``splits``: the episode range ``"a:b"`` of each non-empty split."""
    bounds: dict[str, str] = {}
    start = 0
    for split in SPLITS:
        n = sum(1 for e in episodes if e.split == split)
        if n:
            bounds[split] = f"{start}:{start + n}"
        start += n
    return bounds


def rmi_info(source: Source) -> dict[str, Any]:
    """The ``rmi`` entry of ``info.json``: where the export comes from and what it filled."""
    return {
        "source": str(source.data.resolve()),
        "phases": list(PHASES),
        "nan_fill": 0.0,
        "split_seed": source.info.get("seed"),
    }
