"""The runs' trial configs: a resumed sweep refuses runs of another engine config."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest
from sweep_doubles import fake_make_config, fake_runner, grid, other_engine_make_config

from rmi_learn.data.sweep.configs import with_later_fields
from rmi_learn.data.sweep.grid import expand_grid
from rmi_learn.data.sweep.run import run_sweep


def test_resume_refuses_runs_of_another_engine_config(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    g = grid(hold_forces_N=[30], porosities=[0.5])
    sweep = functools.partial(
        run_sweep, expand_grid(g), out, runner=fake_runner, workers=0, progress=False, grid=g
    )
    sweep(make_config=fake_make_config)
    before = {p: p.read_bytes() for p in (out / "runs").rglob("*.parquet")}
    with pytest.raises(
        ValueError, match=r"2 finished run\(s\).*material: <absent> -> \{'permeability': 3e-11\}"
    ):
        sweep(make_config=other_engine_make_config)
    # Nothing was touched: the old runs stay as they were.
    assert {p: p.read_bytes() for p in (out / "runs").rglob("*.parquet")} == before


def test_a_stored_config_without_later_fields_reads_as_their_defaults() -> None:
    import rmi_sph

    default = rmi_sph.default_config()
    stored = json.loads(json.dumps(default))
    del stored["pressure"]["single_solve"]
    del stored["controller"]["perturbation"]
    assert with_later_fields(stored, default) == default
    # A stored value is kept: a run made with the option on stays different.
    stored["pressure"]["single_solve"] = True
    assert with_later_fields(stored, default)["pressure"]["single_solve"] is True
