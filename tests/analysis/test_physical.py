"""``rmi analyze`` end to end on the synthetic toy runs (whose numbers mean nothing
physically: only the plumbing, the files and the JSON are checked on them)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from rmi_learn.analysis import physical
from rmi_learn.analysis.physical import FIGURES, JSON_FILE, analyze
from rmi_learn.analysis.run_table import load_runs
from rmi_learn.cli import main as cli_main
from rmi_learn.data.runs import write_error
from rmi_learn.data.sweep import build_index

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# ---- end to end on the synthetic toy runs ----------------------------------------------


def _strict_json(path: Path) -> Any:
    def no_nan(token: str) -> Any:
        raise AssertionError(f"{path} holds {token}")

    return json.loads(path.read_text(), parse_constant=no_nan)


def _check_outputs(out: Path) -> dict[str, Any]:
    for name in FIGURES.values():
        data = (out / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 5000, name
    assert not list(out.glob(".*.tmp"))
    result: dict[str, Any] = _strict_json(out / JSON_FILE)
    return result


def test_cli_on_bare_synthetic_tree(
    synthetic_runs_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "analysis"
    rc = cli_main(["analyze", "--runs", str(synthetic_runs_dir), "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "squeeze association" in printed and "synthetic" in printed
    res = _check_outputs(out)
    assert res["synthetic"] is True
    assert res["input"]["read_from"] == "bare runs tree"
    c = res["counts"]
    assert c["runs_total"] == 36 and c["ok"] == 36 and c["failed"] == c["unstable"] == 0
    assert c["lift_success"] == 24 and c["stable_squeeze"] == 18
    single = res["single_run"]
    assert single["lift_success"] and single["stable_squeeze"]
    assert single["params"]["size_cm"] == 10  # the median size of the grid
    # Lift failures never reach waiting/squeeze; every run reaches the grasp phases.
    per = res["water_per_phase"]["per_phase"]
    assert per["ramp"]["n"] == 36 and per["squeeze"]["n"] == 24
    assert res["water_removed_median_g"]["ramp"] == per["ramp"]["median"]
    assert "synthetic" in res["summary_text"]
    assert res["squeeze_association"]["status"] == "ok"
    assert res["squeeze_association"]["n_groups"] == 12
    assert res["squeeze_association"]["per_size"]["8"]["caution"]  # 4 groups only
    assert res["paper"]["squeeze_association"]["slope_g_per_N"] == 0.669
    assert res["paper"]["water_per_phase"]["median_g"] is None


def test_analyze_sweep_directory_with_index_and_failures(
    synthetic_runs_dir: Path, tmp_path: Path
) -> None:
    sweep = tmp_path / "sweep"
    shutil.copytree(synthetic_runs_dir, sweep / "runs")
    params = {"size_cm": 10, "porosity": 0.6, "F_hold": 500.0, "F_squeeze": 150.0, "seed": 0}
    write_error(
        sweep / "runs" / "size_cm=10/porosity=0.6/F_hold=500/F_squeeze=150/seed=0",
        params,
        {"status": "unstable", "error": "SimulationUnstableError: boom", "wall_s": 1.0},
    )
    rebuilt = load_runs(sweep)  # no index yet: rebuilt from runs/
    assert rebuilt.origin == "sweep tree" and rebuilt.index.height == 37
    build_index(sweep)
    chosen = "size_cm=8/porosity=0.5/F_hold=30/F_squeeze=150/seed=0"
    res = analyze(sweep, tmp_path / "out", run_id=chosen, n_boot=200)
    _check_outputs(tmp_path / "out")
    assert res["input"]["read_from"] == "index.parquet"
    assert res["counts"]["runs_total"] == 37 and res["counts"]["unstable"] == 1
    assert res["single_run"]["run_id"] == chosen
    assert res["single_run"]["selection"]["rule"] == "chosen with --run-id"
    # The unstable run's grid cell (F_hold 500 N) has no usable run.
    assert 500.0 not in res["lift_success"]["F_hold_values"]


def test_figures_are_written_atomically(
    synthetic_runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def boom(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("killed while plotting")

    monkeypatch.setattr(physical, "plot_lift_success", boom)
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        analyze(synthetic_runs_dir, out, n_boot=50)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([FIGURES["single_run"], FIGURES["water_per_phase"]])
    for name in names:
        assert (out / name).read_bytes().startswith(PNG_MAGIC)


@pytest.mark.parametrize("case", ["missing", "empty", "unknown-run"])
def test_cli_errors_exit_2_without_traceback(
    case: str, synthetic_runs_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = {"missing": tmp_path / "nope", "empty": tmp_path, "unknown-run": synthetic_runs_dir}
    argv = ["analyze", "--runs", str(runs[case]), "--out", str(tmp_path / "out")]
    if case == "unknown-run":
        argv += ["--run-id", "size_cm=9/porosity=0.1/F_hold=1/F_squeeze=1/seed=0"]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("rmi analyze: ")
    assert "Traceback" not in err
    assert not (tmp_path / "out" / JSON_FILE).exists()
