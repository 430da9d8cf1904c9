"""``rmi view``: a rerun recording of simulated trials, the one line that says how to
install rerun-sdk when it is missing, and the folders of the recording (made when missing,
removed again when the write fails; checked with a stand-in for rerun-sdk)."""

from __future__ import annotations

import errno
import itertools
import json
import sys
import types
from pathlib import Path
from unittest import mock

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


class FakeStream:
    """The part of rerun's RecordingStream that ``rmi view`` uses: its file sink writes at
    once; ``fail`` makes the flush fail as a full disk would."""

    fail = False

    def __init__(self, name: str) -> None:
        self.path: Path | None = None

    def save(self, path: Path) -> None:
        self.path = Path(path)
        self.path.write_bytes(b"a recording")

    def log(self, *args: object, **kwargs: object) -> None:
        pass

    send_columns = set_time = log

    def flush(self) -> None:
        if self.fail:
            raise OSError(errno.ENOSPC, "No space left on device")

    def disconnect(self) -> None:
        pass


@pytest.fixture
def fake_rerun(monkeypatch: pytest.MonkeyPatch) -> type[FakeStream]:
    """A stand-in for rerun-sdk, so that where the recording goes is tested without it."""
    module = types.ModuleType("rerun")
    for name in ("ViewCoordinates", "TimeColumn", "Scalars", "TextLog", "Points3D", "Mesh3D"):
        setattr(module, name, mock.MagicMock())
    stream = type("Stream", (FakeStream,), {})
    module.RecordingStream = stream  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "rerun", module)
    return stream


def test_the_folders_of_the_recording_are_made(
    tmp_path: Path, run_dir: Path, fake_rerun: type[FakeStream]
) -> None:
    rrd = tmp_path / "missing" / "folder" / "one.rrd"
    assert main(["view", "--rrd", str(rrd), str(run_dir)]) == 0
    assert rrd.read_bytes() == b"a recording"
    assert [p.name for p in rrd.parent.iterdir()] == ["one.rrd"]


def test_a_recording_that_cannot_be_written_leaves_nothing(
    tmp_path: Path,
    run_dir: Path,
    fake_rerun: type[FakeStream],
    capsys: pytest.CaptureFixture[str],
) -> None:
    fake_rerun.fail = True
    rrd = tmp_path / "missing" / "one.rrd"
    assert main(["view", "--rrd", str(rrd), str(run_dir)]) == 2
    assert "No space left on device" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_recording_in_a_missing_folder_is_written(
    tmp_path: Path, run_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pytest.importorskip("rerun")
    rrd = tmp_path / "missing" / "one.rrd"
    assert main(["view", "--rrd", str(rrd), str(run_dir)]) == 0
    assert f"wrote {rrd}: 1 run(s)" in capsys.readouterr().out
    assert [p.name for p in rrd.parent.iterdir()] == ["one.rrd"]
