"""The run-file contract is enforced on read: a file written by other tools with a missing
channel, another type, a null, NaN outside ``v_res`` or inf anywhere is refused by
``read_run`` and by the dataset builder, naming the file and the column."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from rmi_learn.data.dataset import build_dataset
from rmi_learn.data.runs import read_run, run_id, run_path, write_run
from rmi_learn.data.schema import SEED_MAX
from rmi_learn.data.synthetic import simulate_toy_run
from rmi_learn.errors import RunFileError

PARAMS = {"size_cm": 8, "porosity": 0.5, "F_hold": 30.0, "F_squeeze": 150.0, "seed": 0}


def run_file(root: Path) -> Path:
    res = simulate_toy_run(8, 0.5, 30.0, 150.0, 0)
    return write_run(run_path(root, PARAMS), res["columns"], {}, PARAMS, res["outcome"])


def rewrite(path: Path, expr: pl.Expr) -> None:
    """Rewrite a run file with one column replaced by ``expr``, keeping its metadata."""
    meta = pl.read_parquet_metadata(path)
    pl.read_parquet(path).with_columns(expr).write_parquet(path, metadata=meta)


def first_row(name: str, value: float) -> pl.Expr:
    return pl.when(pl.int_range(pl.len()) == 0).then(value).otherwise(pl.col(name)).alias(name)


@pytest.mark.parametrize(
    ("expr", "column", "says"),
    [
        (first_row("F_meas", math.inf), "F_meas", "non-finite"),
        (first_row("F_meas", math.nan), "F_meas", "non-finite"),
        (first_row("v_res", -math.inf), "v_res", "infinite"),
        (first_row("M_L", None), "M_L", "null"),  # type: ignore[arg-type]
        (pl.col("time").cast(pl.Int64), "time", "the contract says Float64"),
        (pl.col("gate_open").cast(pl.Float64), "gate_open", "the contract says Boolean"),
        (pl.col("time").reverse(), "time", "does not increase"),
    ],
    ids=["inf", "nan", "inf-in-v_res", "null", "int-time", "float-gate", "time-order"],
)
def test_read_run_refuses_a_file_that_breaks_the_contract(
    tmp_path: Path, expr: pl.Expr, column: str, says: str
) -> None:
    path = run_file(tmp_path)
    rewrite(path, expr)
    with pytest.raises(RunFileError, match=says) as info:
        read_run(path)
    assert str(path) in str(info.value) and repr(column) in str(info.value)


def test_read_run_refuses_a_missing_channel_and_accepts_nan_in_v_res(tmp_path: Path) -> None:
    path = run_file(tmp_path)
    rewrite(path, first_row("v_res", math.nan))
    frame, _ = read_run(path)
    assert np.isnan(frame["v_res"][0])
    meta = pl.read_parquet_metadata(path)
    pl.read_parquet(path).drop("A_L").write_parquet(path, metadata=meta)
    with pytest.raises(RunFileError, match=r"missing column\(s\) \['A_L'\]"):
        read_run(path)


def test_the_dataset_builder_refuses_a_non_finite_load(tmp_path: Path) -> None:
    path = run_file(tmp_path / "runs")
    rewrite(path, first_row("F_meas", math.inf))
    out = tmp_path / "ds"
    with pytest.raises(RunFileError, match="'F_meas'"):
        build_dataset(tmp_path / "runs", out)
    assert not (out / "frames.parquet").exists()


def test_every_seed_of_the_range_names_its_own_run_and_one_beyond_is_refused(
    tmp_path: Path,
) -> None:
    res = simulate_toy_run(8, 0.5, 30.0, 150.0, 0)
    for seed in (2**53, 2**53 + 1, SEED_MAX):
        params = {**PARAMS, "seed": seed}
        assert run_id(params).endswith(f"/seed={seed}")  # exactly, not through a float
        path = write_run(run_path(tmp_path, params), res["columns"], {}, params, res["outcome"])
        assert read_run(path)[1]["params"]["seed"] == seed
    beyond = {**PARAMS, "seed": SEED_MAX + 1}
    with pytest.raises(
        RunFileError, match=rf"param 'seed' must be an integer in \[0, {SEED_MAX}\]"
    ):
        write_run(run_path(tmp_path, beyond), res["columns"], {}, beyond, res["outcome"])
