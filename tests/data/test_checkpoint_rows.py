"""Checkpointed result rows: written atomically with their metadata, and a write that
fails (a full disk) is an OSError naming the file, never a polars error."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import polars as pl
import pytest

from rmi_learn.data import checkpoint_rows
from rmi_learn.data.checkpoint_rows import read_rows, write_rows
from rmi_learn.data.runs import atomic_write_bytes

SCHEMA = {"run_id": pl.String, "t": pl.Int64, "err_g": pl.Float64}
ROWS = [{"run_id": "a", "t": 3, "err_g": 0.5}, {"run_id": "b", "t": 4}]


class FullDisk:
    """A file on a full disk: every write fails with ENOSPC."""

    def write(self, data: object) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def full_disk(monkeypatch: pytest.MonkeyPatch, module: Any) -> None:
    """``module``'s atomic writes get a file on a full disk."""

    def atomic(path: Path, writer: Any) -> Path:
        return atomic_write_bytes(path, lambda f: writer(FullDisk()))

    monkeypatch.setattr(module, "atomic_write_bytes", atomic)


def test_rows_and_metadata_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "rows.parquet"
    write_rows(path, ROWS, SCHEMA, {"rmi.fingerprint": "abc"})
    meta, frame = read_rows(path)
    assert meta["rmi.fingerprint"] == "abc"
    assert frame.columns == list(SCHEMA) and frame["err_g"].to_list() == [0.5, None]


def test_a_full_disk_is_an_os_error_naming_the_file_and_keeps_the_old_rows(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "rows.parquet"
    write_rows(path, ROWS[:1], SCHEMA, {"rmi.fingerprint": "abc"})
    before = path.read_bytes()
    full_disk(monkeypatch, checkpoint_rows)
    with pytest.raises(OSError) as err:
        write_rows(path, ROWS, SCHEMA, {"rmi.fingerprint": "abc"})
    assert err.value.errno == errno.ENOSPC and err.value.filename == str(path)
    assert path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [
        "rows.parquet"
    ]
