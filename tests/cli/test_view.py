"""``rmi view``: a rerun recording of simulated trials, and the one line that says how to
install rerun-sdk when it is missing."""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path

import pytest

from rmi_learn.cli import main
from tiny_trial import tiny_config


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny trial simulated with a VTK frame every 100 steps."""
    root = tmp_path_factory.mktemp("view")
    config = root / "trial.json"
    config.write_text(json.dumps(tiny_config()))
    out = root / "one"
    argv = ["simulate", "--config", str(config), "--out", str(out), "--vtk-every", "100"]
    assert main([*argv, "--threads", "1", "--quiet"]) == 0
    return out


def test_without_rerun_one_line_says_how_to_install_it(
    tmp_path: Path,
    run_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` now fails
    capsys.readouterr()
    rrd = tmp_path / "one.rrd"
    assert main(["view", "--rrd", str(rrd), str(run_dir)]) == 1
    assert capsys.readouterr().err.splitlines() == [
        "rmi view: needs rerun-sdk, which is not installed: pip install rerun-sdk"
    ]
    assert list(tmp_path.iterdir()) == []


def test_a_directory_without_a_run_is_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rrd = tmp_path / "one.rrd"
    assert main(["view", "--rrd", str(rrd), str(tmp_path)]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("rmi view: ") and "no run file" in line and str(tmp_path) in line
    assert not rrd.exists()


def test_the_recording_holds_particles_bodies_and_series_on_one_timeline(
    tmp_path: Path, run_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader  # type: ignore[import-not-found,unused-ignore]

    from rmi_learn.data.runs import read_run

    rrd = tmp_path / "one.rrd"
    assert main(["view", "--rrd", str(rrd), str(run_dir), str(run_dir)]) == 0
    assert f"wrote {rrd}: 2 run(s)" in capsys.readouterr().out
    assert [p.name for p in tmp_path.iterdir()] == ["one.rrd"]
    rows: dict[str, int] = {}
    for chunk in RrdReader(rrd).stream():
        if not chunk.is_static:
            assert "time" in chunk.timeline_names, chunk.entity_path
        rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    df, _ = read_run(run_dir / "run.parquet")
    frames = len(list((run_dir / "frames").glob("particles_*.vtp")))
    changes = 1 + sum(a != b for a, b in itertools.pairwise(df["phase"].to_list()))
    for name in ("one", "one_1"):  # the same run twice: two entities
        root = f"/runs/{name}"
        assert rows[f"{root}/force/F_meas"] == df.height
        assert rows[f"{root}/water/retained_g"] == df.height
        assert rows[f"{root}/particles/water"] == frames
        assert rows[f"{root}/particles/skeleton"] == frames
        assert rows[f"{root}/bodies"] == frames
        assert rows[f"{root}/phase"] == changes
