"""LeRobot's codebase v2.1 layout, for tools that still read it: one Parquet file per episode
and JSON Lines metadata::

    data/chunk-000/episode_000000.parquet   one file per episode (1000 episodes per chunk)
    meta/info.json                          version, fps, counts, splits, path template, features
    meta/episodes.jsonl                     episode_index, tasks, length, run_id, split
    meta/tasks.jsonl                        task_index, task (one task)
    meta/episodes_stats.jsonl               per episode: mean, std, min, max, count per feature
    meta/stats.json                         the same over every frame
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import polars as pl

from rmi_learn.data import staging
from rmi_learn.data.export_lerobot import stats
from rmi_learn.data.export_lerobot.episodes import (
    ROBOT_TYPE,
    TASK,
    Episode,
    Source,
    features,
    rmi_info,
    split_bounds,
)

VERSION = "v2.1"
#: Episodes per ``data/chunk-NNN`` directory (LeRobot's default).
CHUNKS_SIZE = 1000
DATA_PATH = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"


def write_json(path: Path, obj: Any) -> None:
    path.write_text(json.dumps(obj, indent=2) + "\n", encoding="utf-8")


def _write_jsonl(path: Path, records: list[dict[str, Any]]) -> None:
    path.write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")


def write(tmp: Path, source: Source, episodes: list[Episode]) -> None:
    """Write the v2.1 export of ``episodes`` into the directory ``tmp``."""
    (tmp / "meta").mkdir()
    for e in episodes:
        path = tmp / DATA_PATH.format(episode_chunk=e.index // CHUNKS_SIZE, episode_index=e.index)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(staging.parquet_bytes(e.table))
    meta = [
        {"episode_index": e.index, "tasks": [TASK], "length": e.table.height,
         "run_id": e.run_id, "split": e.split}
        for e in episodes
    ]  # fmt: skip
    ep_stats = [{"episode_index": e.index, "stats": stats.table_stats(e.table)} for e in episodes]
    write_json(
        tmp / "meta" / "info.json",
        {
            "codebase_version": VERSION,
            "robot_type": ROBOT_TYPE,
            "total_episodes": len(episodes),
            "total_frames": sum(e.table.height for e in episodes),
            "total_tasks": 1,
            "total_videos": 0,
            "total_chunks": (len(episodes) - 1) // CHUNKS_SIZE + 1,
            "chunks_size": CHUNKS_SIZE,
            "fps": source.fps,
            "splits": split_bounds(episodes),
            "data_path": DATA_PATH,
            "video_path": None,
            "features": features(source.u_names),
            "rmi": rmi_info(source),
        },
    )
    _write_jsonl(tmp / "meta" / "tasks.jsonl", [{"task_index": 0, "task": TASK}])
    _write_jsonl(tmp / "meta" / "episodes.jsonl", meta)
    _write_jsonl(tmp / "meta" / "episodes_stats.jsonl", ep_stats)
    all_frames = pl.concat([e.table for e in episodes])
    write_json(tmp / "meta" / "stats.json", stats.table_stats(all_frames))
