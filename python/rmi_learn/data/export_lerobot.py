"""Export of a built learning dataset to LeRobot's dataset layout (codebase version v2.1):
:func:`export_lerobot` (``rmi dataset export --format lerobot``).

The export needs polars and numpy only, not the ``lerobot`` package. One episode per run,
on the dataset's control grid (20 ms, 50 fps), in the rows the dataset keeps (the learning
phases). Written under ``out_dir``::

    data/chunk-000/episode_000000.parquet   one file per episode (1000 episodes per chunk)
    meta/info.json                          version, fps, counts, splits, path template, features
    meta/episodes.jsonl                     episode_index, tasks, length, run_id, split
    meta/tasks.jsonl                        task_index, task (one task)
    meta/episodes_stats.jsonl               per episode: mean, std, min, max, count per feature
    meta/stats.json                         the same over every frame

Columns of an episode file (the features of ``info.json``):

- ``observation.state`` (list<float32>, 23): the observation ``y_t`` in ``schema.OBS``
  order, SI units. A value the dataset holds as NaN (only ``v_res``, undefined without
  contact) is written as 0, and ``observation.state_mask`` (list<float32>, 23) is 1 where
  the value was finite and 0 where it was filled, as the world models' ``hist_mask``.
- ``action`` (list<float32>): the action channels the dataset was built with, named by its
  ``stats.json`` (``u_names``).
- ``timestamp`` (float32, s): ``frame_index / fps``. LeRobot requires consecutive
  timestamps one frame apart, while the dataset drops the ``waiting`` phase between lift
  and squeeze; ``sim_time`` (float32, s) keeps the simulated time of each frame, so the
  jump at that gap shows there.
- ``phase_index`` (int64): the controller phase, an index into ``schema.PHASES``.
- ``frame_index``, ``episode_index``, ``index`` (global frame number), ``task_index``
  (int64) and ``next.done`` (bool, true on an episode's last frame).

Episodes are ordered by split (train, val, test), then by the dataset's run number, so that
``info.json``'s ``splits`` are the ranges ``"0:a"``, ``"a:b"``, ``"b:n"`` of the dataset's
own grouped split (an empty split is left out). Statistics are population statistics of the
exported values (the filled zeros included) over every frame, as LeRobot computes them; the
dataset's own ``stats.json`` covers the training split only.

The export is written into a temporary directory beside ``out_dir`` and renamed to it at
the end, so ``out_dir`` either does not exist or holds a complete export; the temporary
directory of an export that was killed is removed by the next export into the same
directory (see :mod:`rmi_learn.data.staging`).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data import staging
from rmi_learn.data.dataset import FORMAT_VERSION, SPLITS, read_table
from rmi_learn.data.schema import OBS, PHASES
from rmi_learn.errors import InputError

CODEBASE_VERSION = "v2.1"
#: Episodes per ``data/chunk-NNN`` directory (LeRobot's default).
CHUNKS_SIZE = 1000
DATA_PATH = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
ROBOT_TYPE = "rmi_parallel_gripper"
TASK = "grasp, lift and squeeze the water-filled sponge"

#: Features of every episode file, in column order: (name, dtype); the vector features'
#: shapes and names are filled in by :func:`features`.
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
    channel names of every column of an episode file."""
    out: dict[str, dict[str, Any]] = {
        "observation.state": {"dtype": "float32", "shape": [len(OBS)], "names": list(OBS)},
        "observation.state_mask": {"dtype": "float32", "shape": [len(OBS)], "names": list(OBS)},
        "action": {"dtype": "float32", "shape": [len(u_names)], "names": list(u_names)},
    }
    for name, dtype in _SCALARS:
        out[name] = {"dtype": dtype, "shape": [1], "names": None}
    return out


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


def feature_stats(values: np.ndarray) -> dict[str, list[float]]:
    """Population statistics of one feature over its frames: ``values`` is (frames,) or
    (frames, channels); returns ``mean``, ``std``, ``min``, ``max`` (one entry per channel,
    in the feature's unit) and ``count`` ([frames])."""
    x = values.astype(np.float64)
    if x.ndim == 1:
        x = x[:, None]
    return {
        "mean": x.mean(axis=0).tolist(),
        "std": x.std(axis=0).tolist(),
        "min": x.min(axis=0).tolist(),
        "max": x.max(axis=0).tolist(),
        "count": [int(x.shape[0])],
    }


def _episode(
    rows: pl.DataFrame, u_names: list[str], episode: int, first_index: int, fps: int
) -> dict[str, np.ndarray]:
    """The columns of one episode file as numpy arrays (vectors as 2-D arrays)."""
    n = rows.height
    y = rows.select(OBS).to_numpy().astype(np.float64)
    finite = np.isfinite(y)
    frame = np.arange(n, dtype=np.int64)
    phase = {p: i for i, p in enumerate(PHASES)}
    return {
        "observation.state": np.where(finite, y, 0.0).astype(np.float32),
        "observation.state_mask": finite.astype(np.float32),
        "action": rows.select(u_names).to_numpy().astype(np.float32),
        "sim_time": rows["time"].to_numpy().astype(np.float32),
        "phase_index": np.array([phase[p] for p in rows["phase"].to_list()], dtype=np.int64),
        "next.done": frame == n - 1,
        "timestamp": (frame / fps).astype(np.float32),
        "frame_index": frame,
        "episode_index": np.full(n, episode, dtype=np.int64),
        "index": first_index + frame,
        "task_index": np.zeros(n, dtype=np.int64),
    }


def _table(cols: dict[str, np.ndarray], feats: dict[str, dict[str, Any]]) -> pl.DataFrame:
    series = []
    for name, arr in cols.items():
        dtype = _POLARS[feats[name]["dtype"]]
        if arr.ndim == 2:
            series.append(pl.Series(name, arr).cast(pl.List(dtype)))
        else:
            series.append(pl.Series(name, arr, dtype=dtype))
    return pl.DataFrame(series)


def _write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=2) + "\n", encoding="utf-8")


def _write_jsonl(path: Path, records: list[dict[str, Any]]) -> None:
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")


def _check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"--out {out} exists and is not an empty directory; choose a new one")


def export_lerobot(data_dir: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> Path:
    """Export the dataset built in ``data_dir`` (``rmi dataset build``) to LeRobot's v2.1
    layout in ``out_dir`` and return ``out_dir`` (see the module docstring for the files and
    columns). ``out_dir`` must not exist or be an empty directory; a symbolic link to an
    empty directory is kept, and the export written where it points.

    Raises :class:`~rmi_learn.errors.InputError` for an ``out_dir`` that holds anything, a
    damaged dataset, one without the named action channels or with a phase that is not one
    of ``schema.PHASES``; FileNotFoundError when ``data_dir`` is not a built dataset; an
    OSError naming ``out_dir`` (or the file in it) when the export cannot be written.
    """
    data, out = Path(data_dir), Path(out_dir)
    _check_out(out)
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
    episodes = sorted(
        runs.select("run", "run_id", "split").rows(), key=lambda r: (order[r[2]], r[0])
    )
    by_run = {int(key[0]): g.sort("t") for key, g in frames.group_by("run")}
    # Through a link to a directory the export goes where the link points; the link stays.
    target = Path(os.path.realpath(out))
    with staging.staged(target.parent, target.name, out) as tmp:
        _write_export(tmp, data, info, fps, u_names, episodes, by_run)
        _check_out(out)  # again: another writer may have filled it meanwhile
        if target.exists():
            target.rmdir()
        os.rename(tmp, target)
    return out


def _check_phases(frames: pl.DataFrame, path: Path) -> None:
    """Refuse frames whose ``phase`` is not a name of ``schema.PHASES`` (it has no index)."""
    unknown = sorted(set(frames["phase"].unique().to_list()) - set(PHASES), key=str)
    if unknown:
        names = ", ".join(repr(p) for p in unknown)
        raise InputError(
            f"{path}: unknown phase {names} in column 'phase'; accepted: {', '.join(PHASES)}"
        )


def _write_export(
    tmp: Path,
    data: Path,
    info: dict[str, Any],
    fps: int,
    u_names: list[str],
    episodes: list[tuple[Any, ...]],
    by_run: dict[int, pl.DataFrame],
) -> None:
    """Write every file of the export into the directory ``tmp``."""
    feats = features(u_names)
    (tmp / "meta").mkdir()
    tables: list[pl.DataFrame] = []
    meta: list[dict[str, Any]] = []
    ep_stats: list[dict[str, Any]] = []
    total = 0
    for run, run_id, split in episodes:
        rows = by_run.get(int(run))
        if rows is None or rows.height == 0:
            continue  # a run without kept rows has no frames to export
        ep = len(meta)
        table = _table(_episode(rows, u_names, ep, total, fps), feats)
        path = tmp / DATA_PATH.format(episode_chunk=ep // CHUNKS_SIZE, episode_index=ep)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(staging.parquet_bytes(table))
        tables.append(table)
        meta.append(
            {
                "episode_index": ep,
                "tasks": [TASK],
                "length": table.height,
                "run_id": run_id,
                "split": split,
            }
        )
        ep_stats.append({"episode_index": ep, "stats": table_stats(table)})
        total += table.height
    if not meta:
        raise InputError(f"{data}: the dataset has no frames to export")
    bounds: dict[str, str] = {}
    start = 0
    for split in SPLITS:
        n = sum(1 for m in meta if m["split"] == split)
        if n:
            bounds[split] = f"{start}:{start + n}"
        start += n
    _write_json(
        tmp / "meta" / "info.json",
        {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": ROBOT_TYPE,
            "total_episodes": len(meta),
            "total_frames": total,
            "total_tasks": 1,
            "total_videos": 0,
            "total_chunks": (len(meta) - 1) // CHUNKS_SIZE + 1,
            "chunks_size": CHUNKS_SIZE,
            "fps": fps,
            "splits": bounds,
            "data_path": DATA_PATH,
            "video_path": None,
            "features": feats,
            "rmi": {
                "source": str(data.resolve()),
                "phases": list(PHASES),
                "nan_fill": 0.0,
                "split_seed": info.get("seed"),
            },
        },
    )
    _write_jsonl(tmp / "meta" / "tasks.jsonl", [{"task_index": 0, "task": TASK}])
    _write_jsonl(tmp / "meta" / "episodes.jsonl", meta)
    _write_jsonl(tmp / "meta" / "episodes_stats.jsonl", ep_stats)
    _write_json(tmp / "meta" / "stats.json", table_stats(pl.concat(tables)))


def table_stats(table: pl.DataFrame) -> dict[str, dict[str, list[float]]]:
    """:func:`feature_stats` of every column of an episode table (or of several stacked)."""
    out: dict[str, dict[str, list[float]]] = {}
    for name in table.columns:
        s = table[name]
        if isinstance(s.dtype, pl.List):
            width = len(s[0])
            values = s.list.to_array(width).to_numpy()
        else:
            values = s.to_numpy()
        out[name] = feature_stats(values)
    return out
