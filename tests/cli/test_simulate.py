"""``rmi simulate`` on the command line: its progress line on stderr and ``--quiet``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rmi_learn.cli import main, simulate
from tiny_trial import tiny_config


@pytest.fixture
def config_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    # Every chunk of steps prints, so that the tiny trial (about 1 s) shows its lines.
    monkeypatch.setattr(simulate, "PROGRESS_EVERY_S", {True: 0.0, False: 0.0})
    path = tmp_path / "trial.json"
    path.write_text(json.dumps(tiny_config()))
    return path


def test_simulate_prints_progress_lines_on_stderr(
    tmp_path: Path, config_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["simulate", "--config", str(config_file), "--out", str(tmp_path / "o")]
    assert main([*argv, "--threads", "1"]) == 0
    out, err = capsys.readouterr()
    progress = [ln for ln in err.splitlines() if ln.startswith("rmi simulate: phase ")]
    assert len(progress) >= 2 and "steps/s" in progress[-1] and "phase done" in progress[-1]
    assert "of at most" in progress[0]
    # stdout keeps only the outcome, as JSON.
    assert json.loads(out)["lift_success"] in (True, False)


@pytest.mark.parametrize("flag", ["--quiet", "--no-progress"])
def test_quiet_prints_no_progress(
    tmp_path: Path, config_file: Path, capsys: pytest.CaptureFixture[str], flag: str
) -> None:
    argv = ["simulate", "--config", str(config_file), "--out", str(tmp_path / "o")]
    assert main([*argv, "--threads", "1", flag]) == 0
    err = capsys.readouterr().err
    assert "phase" not in err and err.startswith("run file: ")
