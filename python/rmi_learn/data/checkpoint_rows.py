"""Checkpointed result rows: a table of result rows in a Parquet file, rewritten atomically
after every unit of work and tied to its inputs by a fingerprint in the file's metadata, so
that an interrupted command resumes where it stopped and never mixes results of other
inputs. The commands that checkpoint (``rmi closed-loop``, ``rmi control-bench``) check the
stored fingerprint and columns themselves, with their own advice."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import polars as pl

from rmi_learn.data.runs import atomic_write_bytes
from rmi_learn.data.staging import parquet_bytes


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes (hex), read in blocks: an input's part of a fingerprint."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def rows_frame(rows: Sequence[Mapping[str, Any]], schema: Mapping[str, Any]) -> pl.DataFrame:
    """The rows as a frame with exactly the columns and types of ``schema`` (None where a
    row lacks a column)."""
    return pl.DataFrame(
        [pl.Series(c, [r.get(c) for r in rows], dtype=d) for c, d in schema.items()]
    )


def write_rows(
    path: Path,
    rows: Sequence[Mapping[str, Any]],
    schema: Mapping[str, Any],
    metadata: Mapping[str, str],
) -> None:
    """Write the rows (see :func:`rows_frame`) to ``path`` atomically, with ``metadata``; a
    write that fails (a full disk) raises its OSError naming ``path``."""
    data = parquet_bytes(rows_frame(rows, schema), metadata)
    atomic_write_bytes(path, lambda f: f.write(data))


def read_rows(path: Path) -> tuple[dict[str, str], pl.DataFrame]:
    """The metadata and the rows of a checkpoint file. Whatever makes the file unreadable
    propagates, for the command to name with its own advice."""
    return pl.read_parquet_metadata(path), pl.read_parquet(path)


__all__ = ["file_sha256", "read_rows", "rows_frame", "write_rows"]
