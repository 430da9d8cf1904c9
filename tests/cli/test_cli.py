"""The `rmi` entry point's handling of bad input: a message and status 2, not a traceback."""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

import pytest

import rmi_sph
from rmi_learn.cli import main


def test_missing_dataset_is_reported_with_status_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = ["train-policy", "--objective", "flow", "--data", str(tmp_path / "nope"), "--out"]
    assert main([*argv, str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rmi train-policy: ") and "not a built dataset" in err
    assert "Traceback" not in err and not out.exists()


def test_dataset_names_a_missing_run_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "runs"
    assert main(["dataset", "--runs", str(missing), "--out", str(tmp_path / "ds")]) == 2
    err = capsys.readouterr().err
    assert f"{missing} is not a directory of runs" in err
    assert not (tmp_path / "ds").exists()


def test_dataset_build_options_may_stand_before_or_after_the_subcommand(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "runs"
    for argv in (
        ["dataset", "--runs", str(missing), "--out", str(tmp_path / "ds"), "build"],
        ["dataset", "--runs", str(missing), "build", "--out", str(tmp_path / "ds")],
    ):
        assert main(argv) == 2
        assert f"{missing} is not a directory of runs" in capsys.readouterr().err
    assert main(["dataset", "build", "--runs", str(missing)]) == 2
    assert "give --runs DIR and --out DIR" in capsys.readouterr().err
    assert not (tmp_path / "ds").exists()


def test_an_output_path_that_is_a_file_is_reported(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    taken = tmp_path / "taken"
    taken.write_text("not a directory")
    assert main(["sweep", "--preset", "tiny", "--out", str(taken)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rmi sweep: ") and str(taken) in err and "Traceback" not in err
    assert taken.read_text() == "not a directory"


def test_a_locked_sweep_directory_is_status_1_not_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Valid input that cannot run now (another sweep writes the directory) is status 1."""
    fcntl = pytest.importorskip("fcntl")
    from rmi_learn.data.sweep import LOCK_FILE

    out = tmp_path / "sweep"
    out.mkdir()
    with open(out / LOCK_FILE, "a+b") as held:
        fcntl.flock(held.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert main(["sweep", "--preset", "tiny", "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("rmi sweep: another sweep is writing") and "Traceback" not in err
    assert not (out / "runs").exists()


def test_a_damaged_run_drawn_by_analyze_is_named_not_a_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`rmi analyze` of a sweep reads the index, then one run file for Fig. 4: when that file
    is damaged the command names it and how to rerun it."""
    from rmi_learn.data.sweep import build_index
    from rmi_learn.data.synthetic import write_synthetic_runs

    sweep = tmp_path / "sweep"
    write_synthetic_runs(sweep / "runs", n_per_size=4, seed=0)
    build_index(sweep)
    damaged = sorted((sweep / "runs").rglob("run.parquet"))
    for f in damaged:
        f.write_bytes(f.read_bytes()[:100])
    assert main(["analyze", "--runs", str(sweep), "--out", str(tmp_path / "an")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rmi analyze: ") and "unreadable run file" in err
    assert any(str(f) in err for f in damaged) and "Traceback" not in err


@pytest.mark.parametrize(
    "exc",
    [
        FileNotFoundError("where"),
        rmi_sph.ConfigError("field"),
        KeyboardInterrupt(),
        RuntimeError("bug"),
    ],
)
def test_input_errors_and_ctrl_c_end_the_command_and_bugs_keep_their_traceback(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], exc: Exception
) -> None:
    module = importlib.import_module("rmi_learn.cli.report")

    def fail(args: argparse.Namespace) -> int:
        raise exc

    monkeypatch.setattr(module, "run", fail)
    if isinstance(exc, RuntimeError):
        with pytest.raises(RuntimeError, match="bug"):
            main(["report", "--out", "x"])
    elif isinstance(exc, KeyboardInterrupt):
        assert main(["report", "--out", "x"]) == 130
        assert capsys.readouterr().err == "rmi report: interrupted\n"
    else:
        assert main(["report", "--out", "x"]) == 2
        assert capsys.readouterr().err.startswith("rmi report: ")


@pytest.mark.parametrize(
    ("argv", "option"),
    [
        (["train-wm", "--model", "ac-gru", "--epochs", "0"], "--epochs"),
        (["train-wm", "--model", "ac-gru", "--batch-size", "0"], "--batch-size"),
        (["train-wm", "--model", "ac-gru", "--seed", "-1"], "--seed"),
        (["train-wm", "--model", "ac-gru", "--lr", "nan"], "--lr"),
        (["train-wm", "--model", "transformer", "--water-weight", "0"], "--water-weight"),
        (["train-policy", "--objective", "flow", "--ema-decay", "1"], "--ema-decay"),
        (["train-policy", "--objective", "flow", "--horizon", "2"], "--horizon"),
        (["train-policy", "--objective", "flow", "--weight-decay", "-1e-3"], "--weight-decay"),
        (["dataset", "--runs", "r", "--seed", "-1"], "--seed"),
        (["sweep", "--preset", "tiny", "--threads-per-run", "0"], "--threads-per-run"),
        (["rank", "--k", "0"], "--k"),
        (["rank", "--force-limit", "inf"], "--force-limit"),
        (["simulate", "--threads", "0"], "--threads"),
        (["train-policy", "--objective", "flow", "--channels", "16,x"], "--channels"),
        (["train-policy", "--objective", "flow", "--channels", "0"], "--channels"),
        (["pipeline", "--preset", "tiny", "--threads", "zero"], "--threads"),
    ],
)
def test_numeric_options_are_checked_when_parsed(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], option: str
) -> None:
    # Out of range: argparse's usage error naming the option and the range, status 2, and
    # nothing created (the command never starts; the value is refused before argparse looks
    # for missing required options).
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as info:
        main([*argv, "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}" in err and "expected" in err
    assert not out.exists()


def test_number_types() -> None:
    from rmi_learn.option_types import count, positive, real

    assert count(0)("0") == 0 and count(1)("7") == 7
    assert positive("1e-4") == 1e-4 and real(0.0, 1.0, high_open=True)("0") == 0.0
    for parse, text in [
        (count(1), "0"),
        (count(0), "1.5"),
        (positive, "0"),
        (positive, "nan"),
        (positive, "-inf"),
        (real(0.0, 1.0, high_open=True), "1"),
        (real(0.0, 1.0), "1.0000001"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match="expected"):
            parse(text)


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--horizon", "30"], "horizon 30 must be divisible by 4"),
        (["--channels", "12,24"], "must be positive multiples of 8"),
    ],
)
def test_policy_shape_errors_come_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], says: str
) -> None:
    # A UNet that cannot be built is reported before the dataset is read or --out exists.
    out = tmp_path / "out"
    argv = ["train-policy", "--objective", "flow", "--data", str(tmp_path / "none")]
    assert main([*argv, "--out", str(out), *extra]) == 2
    assert says in capsys.readouterr().err and not out.exists()


def test_a_closed_loop_error_names_its_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = str(tmp_path / "missing")
    argv = ["closed-loop", "--runs", missing, "--chunks", missing, "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert capsys.readouterr().err.startswith("rmi closed-loop: ")
