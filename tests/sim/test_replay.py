"""Replay of stored runs (rmi_learn.sim.replay): control steps that are whole numbers of engine
steps, the anchor's step count, and the errors for a sweep without an index."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from rmi_learn.data.sweep import INDEX_FILE
from rmi_learn.errors import InputError
from rmi_learn.sim.replay import ReplayError, RunTrack, anchor_step, control_substeps, load_index


def test_control_substeps_divides_the_control_step() -> None:
    assert control_substeps(2e-3) == 10 and control_substeps(1e-3) == 20
    with pytest.raises(ReplayError, match="does not divide the control step"):
        control_substeps(3e-3)


def test_anchor_step_maps_a_kept_row_to_engine_steps() -> None:
    n = 4
    track = RunTrack(
        path=Path("run.parquet"),
        config={},
        size_cm=8,
        k=np.asarray([3, 4, 9, 10]),
        exact=np.ones(n, dtype=bool),
        phase=np.asarray(["hold"] * n),
        obs=np.zeros((n, 23)),
        actions=np.zeros((n, 2)),
    )
    assert [anchor_step(track, t, 2e-3) for t in range(n)] == [30, 40, 90, 100]


def test_a_sweep_without_an_index_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match="index.parquet") as err:
        load_index(tmp_path)
    assert isinstance(err.value, InputError)


def test_a_truncated_index_is_named(tmp_path: Path) -> None:
    """An index cut short (a copy that stopped, a full disk) is a ReplayError naming the
    file and how to rebuild it, not a polars error."""
    pl.DataFrame({"run_id": ["a"], "path": ["runs/a/run.parquet"]}).write_parquet(
        tmp_path / INDEX_FILE
    )
    data = (tmp_path / INDEX_FILE).read_bytes()
    (tmp_path / INDEX_FILE).write_bytes(data[: len(data) // 2])
    with pytest.raises(ReplayError, match="rebuild it with rmi sweep --index-only") as err:
        load_index(tmp_path)
    assert str(err.value).startswith(f"{tmp_path / INDEX_FILE} is not readable")
    assert isinstance(err.value, InputError)
