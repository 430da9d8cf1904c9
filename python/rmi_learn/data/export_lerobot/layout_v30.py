"""LeRobot's codebase v3.0 layout (the one current LeRobot reads): episodes packed into
Parquet files of at most ``DATA_FILE_MB`` megabytes, and Parquet metadata that locates each
episode in them::

    data/chunk-000/file-000.parquet          the frames of consecutive episodes
    meta/info.json                           version, fps, counts, splits, path template,
                                             features
    meta/episodes/chunk-000/file-000.parquet one row per episode: episode_index, tasks,
                                             length, the data file and the global frame range
                                             (dataset_from_index, dataset_to_index), run_id,
                                             split, and its statistics as stats/FEATURE/STAT
    meta/tasks.parquet                       task_index, indexed by the task's text
    meta/stats.json                          statistics over every frame

Files are numbered ``file-NNN`` within ``chunk-NNN`` directories of ``CHUNKS_SIZE`` files. An
episode is never split over two files. The data files carry the ``datasets`` feature types
(fixed-length lists for the vectors) in their schema, and ``tasks.parquet`` the pandas index
that LeRobot reads the task text from; pyarrow writes them (the ``lerobot`` extra), because
the schema metadata polars writes is not what pyarrow reads back.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.data.export_lerobot import episodes as ep
from rmi_learn.data.export_lerobot import stats
from rmi_learn.data.export_lerobot.layout_v21 import write_json
from rmi_learn.errors import InputError

VERSION = "v3.0"
#: Files per ``chunk-NNN`` directory and the size a data file is filled to (LeRobot's).
CHUNKS_SIZE = 1000
DATA_FILE_MB = 100
PATH = "chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
DATA_PATH = "data/" + PATH
EPISODES_PATH = "meta/episodes/" + PATH


def require_pyarrow() -> Any:
    """``pyarrow.parquet``, which writes the schema metadata LeRobot's readers take the task
    text and the feature types from (polars keeps only the file's key-value pairs, which
    pyarrow does not read back); InputError naming the extra that brings it."""
    try:
        import pyarrow.parquet as pq
    except ImportError as exc:
        raise InputError(
            "the LeRobot v3.0 export needs pyarrow: pip install 'rmi[lerobot]' (or pyarrow); "
            "--codebase-version v2.1 writes without it"
        ) from exc
    return pq


def _parquet_bytes(table: pl.DataFrame, metadata: dict[str, str] | None = None) -> bytes:
    """``table`` as Parquet bytes written by pyarrow with ``metadata`` in its schema,
    encoded in memory so that a failing write raises its OSError from Python."""
    import pyarrow as pa

    pq = require_pyarrow()
    arrow = table.to_arrow()
    if metadata:
        arrow = arrow.replace_schema_metadata(metadata)
    sink = pa.BufferOutputStream()
    pq.write_table(arrow, sink, compression="zstd")
    data: bytes = sink.getvalue().to_pybytes()
    return data


def _bytes_per_frame(feats: dict[str, dict[str, Any]]) -> int:
    """Uncompressed bytes of one frame: what a data file's size budget is counted in."""
    size = {"float32": 4, "int64": 8, "bool": 1}
    return sum(size[f["dtype"]] * f["shape"][0] for f in feats.values())


def pack(episodes: list[ep.Episode], frame_bytes: int, limit_mb: float = DATA_FILE_MB) -> list[int]:
    """The data file number of each episode: consecutive episodes share a file until the next
    one would take it over ``limit_mb`` megabytes (uncompressed); a file holds at least one."""
    out: list[int] = []
    file, used = 0, 0
    for e in episodes:
        size = e.table.height * frame_bytes
        if used and used + size > limit_mb * 1024 * 1024:
            file, used = file + 1, 0
        out.append(file)
        used += size
    return out


def hf_features(feats: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The ``datasets`` feature types of the data columns (footer key ``huggingface``)."""
    out: dict[str, Any] = {}
    for name, f in feats.items():
        value = {"dtype": f["dtype"], "_type": "Value"}
        width = f["shape"][0]
        out[name] = value if width == 1 else {"feature": value, "length": width, "_type": "List"}
    return {"info": {"features": out}}


def _tasks_table() -> tuple[pl.DataFrame, dict[str, str]]:
    """``tasks.parquet``: the task index with the task's text as the pandas index."""
    table = pl.DataFrame(
        {"task_index": pl.Series([0], dtype=pl.Int64), "__index_level_0__": [ep.TASK]}
    )
    pandas = {
        "index_columns": ["__index_level_0__"],
        "column_indexes": [],
        "columns": [
            {
                "name": "task_index",
                "field_name": "task_index",
                "pandas_type": "int64",
                "numpy_type": "int64",
                "metadata": None,
            },
            {
                "name": None,
                "field_name": "__index_level_0__",
                "pandas_type": "unicode",
                "numpy_type": "object",
                "metadata": None,
            },
        ],  # fmt: skip
        "creator": {"library": "rmi_learn", "version": "1"},
        "pandas_version": "2.0.0",
    }
    return table, {"pandas": json.dumps(pandas)}


def _episode_rows(
    episodes: list[ep.Episode], files: list[int], feats: dict[str, dict[str, Any]]
) -> pl.DataFrame:
    """``meta/episodes``: one row per episode with its place in the data files and its
    statistics."""
    rows: list[dict[str, Any]] = []
    start = 0
    for e, file in zip(episodes, files, strict=True):
        n = e.table.height
        row: dict[str, Any] = {
            "episode_index": e.index,
            "tasks": [ep.TASK],
            "length": n,
            "data/chunk_index": file // CHUNKS_SIZE,
            "data/file_index": file % CHUNKS_SIZE,
            "dataset_from_index": start,
            "dataset_to_index": start + n,
            "run_id": e.run_id,
            "split": e.split,
        }
        for feature, values in stats.table_stats(e.table, quantiles=True).items():
            for key, v in values.items():
                row[f"stats/{feature}/{key}"] = v
        row["meta/episodes/chunk_index"] = 0
        row["meta/episodes/file_index"] = 0
        rows.append(row)
        start += n
    schema: dict[str, pl.DataType] = {"tasks": pl.List(pl.String())}
    for feature in feats:
        for key in ("mean", "std", "min", "max", *(k for k, _ in stats.QUANTILES)):
            schema[f"stats/{feature}/{key}"] = pl.List(pl.Float64())
        schema[f"stats/{feature}/count"] = pl.List(pl.Int64())
    return pl.DataFrame(rows, schema_overrides=schema)


def write(tmp: Path, source: ep.Source, episodes: list[ep.Episode]) -> None:
    """Write the v3.0 export of ``episodes`` into the directory ``tmp``."""
    feats = ep.features(source.u_names)
    files = pack(episodes, _bytes_per_frame(feats), DATA_FILE_MB)
    footer = {"huggingface": json.dumps(hf_features(feats))}
    for file in sorted(set(files)):
        table = pl.concat([e.table for e, f in zip(episodes, files, strict=True) if f == file])
        path = tmp / DATA_PATH.format(
            chunk_index=file // CHUNKS_SIZE, file_index=file % CHUNKS_SIZE
        )
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(_parquet_bytes(table, footer))
    meta = tmp / "meta"
    ep_path = tmp / EPISODES_PATH.format(chunk_index=0, file_index=0)
    ep_path.parent.mkdir(parents=True)
    ep_path.write_bytes(_parquet_bytes(_episode_rows(episodes, files, feats)))
    tasks, pandas = _tasks_table()
    (meta / "tasks.parquet").write_bytes(_parquet_bytes(tasks, pandas))
    all_frames = pl.concat([e.table for e in episodes])
    write_json(meta / "stats.json", stats.table_stats(all_frames, quantiles=True))
    write_json(
        meta / "info.json",
        {
            "codebase_version": VERSION,
            "robot_type": ep.ROBOT_TYPE,
            "total_episodes": len(episodes),
            "total_frames": int(np.sum([e.table.height for e in episodes])),
            "total_tasks": 1,
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": DATA_FILE_MB,
            "video_files_size_in_mb": 200,
            "fps": source.fps,
            "splits": ep.split_bounds(episodes),
            "data_path": DATA_PATH,
            "video_path": None,
            "features": feats,
            "rmi": ep.rmi_info(source),
        },
    )
