"""Sweep grids: the presets, validation, per-size overrides and perturbed seeds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from sweep_doubles import grid

from rmi_learn.data.schema import FORCE_LIMIT_N
from rmi_learn.data.sweep.grid import expand_grid, load_grid, validate_grid


def test_presets() -> None:
    paper = load_grid("paper")
    assert len(expand_grid(paper)) == 594
    assert paper["sizes_cm"] == [8, 10, 12] and paper["porosities"] == [0.5, 0.6, 0.7]
    assert len(paper["hold_forces_N"]) == 11 and len(paper["squeeze_forces_N"]) == 6
    assert min(paper["hold_forces_N"]) <= 20 and max(paper["hold_forces_N"]) >= 200
    assert 280 <= max(paper["squeeze_forces_N"]) <= FORCE_LIMIT_N
    # The paper's own resolution, same runs; and the timing sample of studies/grids, which
    # must stay a subset of the preset at its resolution and timings.
    fine = load_grid("paper-fine")
    assert fine["radius_m"] == 0.0025 and "dt" not in fine["overrides"]
    assert [s.run_id for s in expand_grid(fine)] == [s.run_id for s in expand_grid(paper)]
    assert fine["radius_m"] < paper["radius_m"]
    sample = load_grid(path=Path(__file__).parents[3] / "studies" / "grids" / "paper-sample.json")
    assert (sample["radius_m"], sample["overrides"]) == (paper["radius_m"], paper["overrides"])
    assert sample["overrides_by_size"] == paper["overrides_by_size"]
    # Per size the converged time step (docs/engine.md): 2 ms for 8 cm, 2.5 ms above.
    dts = {s.params["size_cm"]: s.overrides["dt"] for s in expand_grid(paper)}
    assert dts == {8: 0.002, 10: 0.0025, 12: 0.0025}
    assert "overrides_by_size" not in fine
    assert {s.run_id for s in expand_grid(sample)} < {s.run_id for s in expand_grid(paper)}
    quick, tiny = load_grid("quick"), load_grid("tiny")
    assert 1 < len(expand_grid(tiny)) < len(expand_grid(quick)) < 594
    assert quick["radius_m"] > paper["radius_m"] and tiny["radius_m"] >= quick["radius_m"]
    # A preset is a file: the same file through path= gives the same grid.
    import rmi_learn.data.grids as g

    assert load_grid(path=Path(g.__file__).parent / "quick.json") == quick
    # The control grid: the quick grid's points with three seeds, two of them perturbed.
    control = expand_grid(load_grid("control"))
    assert len(control) == 3 * len(expand_grid(quick))
    perturbed = [s for s in control if "perturbation" in s.overrides]
    assert {s.params["seed"] for s in perturbed} == {1, 2} and len(perturbed) == 2 * 24
    assert all(s.overrides["perturbation"] == {"enabled": True, "seed": s.params["seed"]}
               for s in perturbed)  # fmt: skip


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"hold_forces_N": [10, 401]}, "outside"),
        ({"sizes_cm": [9]}, "sizes_cm"),
        ({"porosities": [1.2]}, "porosity"),
        ({"seeds": [0, 0]}, "duplicates"),
        ({"colour": "red"}, "unknown keys"),
        ({"overrides_by_size": {"10": {"dt": 0.003}}}, "overrides_by_size key '10'"),
        ({"overrides_by_size": {"eight": {}}}, "overrides_by_size key 'eight'"),
        ({"overrides_by_size": {"8": 0.003}}, r"overrides_by_size\['8'\] must be an object"),
        ({"overrides_by_size": [0.003]}, "overrides_by_size must be an object"),
    ],
)
def test_grid_validation(change: dict[str, Any], message: str) -> None:
    base = {
        "sizes_cm": [8],
        "porosities": [0.5],
        "hold_forces_N": [10],
        "squeeze_forces_N": [50],
        "seeds": [0],
        "radius_m": 0.005,
    }
    with pytest.raises(ValueError, match=message):
        validate_grid({**base, **change})


def test_overrides_by_size_apply_to_their_size_only_and_win_over_overrides() -> None:
    g = grid(
        overrides={"dt": 0.002, "hold_time": 1.0},
        overrides_by_size={" 10": {"dt": 0.0025}},
        seeds=[0, 1],
        perturbation={"seeds": [1]},
    )
    assert g["overrides_by_size"] == {"10": {"dt": 0.0025}}
    for spec in expand_grid(g):
        dt = 0.0025 if spec.params["size_cm"] == 10 else 0.002
        assert spec.overrides["dt"] == dt and spec.overrides["hold_time"] == 1.0
        assert ("perturbation" in spec.overrides) == (spec.params["seed"] == 1)
    # A grid without the key keeps its earlier normal form (resumed sweeps compare grids).
    assert "overrides_by_size" not in grid()
