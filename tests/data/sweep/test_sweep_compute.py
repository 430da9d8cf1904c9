"""Computing runs: prefix groups and their fallback, and a refused run file recorded as failed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from sweep_doubles import (
    UNSTABLE_SQUEEZE,
    SimulationUnstableError,
    fake_make_config,
    fake_runner,
    grid,
    nan_runner,
    trial_args,
)

from rmi_learn.data.runs import iter_run_files
from rmi_learn.data.sweep.compute import compute_group, prefix_groups
from rmi_learn.data.sweep.grid import expand_grid
from rmi_learn.data.sweep.run import run_sweep


def test_prefix_groups_and_a_failing_group_falls_back_to_runs_alone(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import rmi_sph

    specs = expand_grid(grid(hold_forces_N=[30], squeeze_forces_N=[150, UNSTABLE_SQUEEZE]))
    configs = {s.run_id: fake_make_config(**trial_args(s)) for s in specs}
    groups = prefix_groups(specs, configs)
    assert [len(g) for g in groups] == [2, 2, 2, 2]  # 2 sizes x 2 porosities
    assert all(len(g) == 1 for g in prefix_groups(specs, configs, runner=fake_runner))
    perturbed = {
        k: {**c, "controller": {"perturbation": {"enabled": True}}} for k, c in configs.items()
    }
    assert all(len(g) == 1 for g in prefix_groups(specs, perturbed))

    # A member that fails makes the group raise: each run is then computed alone, and only
    # the failing one is recorded as failing.
    def group_raises(*_: Any, **__: Any) -> Any:
        raise SimulationUnstableError("velocity blew up in a member's squeeze")

    monkeypatch.setattr(rmi_sph, "run_squeeze_group", group_raises)
    monkeypatch.setattr(rmi_sph, "run_trial", fake_runner)
    g = groups[0]
    results = compute_group(g, [configs[s.run_id] for s in g])
    assert [r["run_id"] for r in results] == [s.run_id for s in g]
    assert [r["status"] for r in results] == ["ok", "unstable"]


def test_run_file_refusal_is_a_recorded_failure(tmp_path: Path) -> None:
    g = grid(sizes_cm=[8], porosities=[0.5], hold_forces_N=[150])
    res = run_sweep(
        expand_grid(g),
        tmp_path / "s",
        runner=nan_runner,
        make_config=fake_make_config,
        workers=0,
        progress=False,
    )
    assert res.failed == 1
    err = res.index["error"][0]
    assert "RunFileError" in err and "'F_L'" in err
    assert not list(iter_run_files(tmp_path / "s"))
