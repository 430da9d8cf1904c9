"""Adversarial input to the `rmi` commands: every case ends with status 2 and one line on
stderr naming the field or path (and the accepted range), and leaves nothing half-written."""

from __future__ import annotations

import argparse
import errno
import io
import json
import os
import re
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import polars as pl
import pytest

from rmi_learn.cli import build_parser, main
from rmi_learn.data.schema import SEED_MAX
from tiny_trial import tiny_config

#: The seeds every command and the engine take, as their errors state them.
SEED_RANGE = f"an integer in [0, {2**63 - 1}]"


def tiny_config_file(directory: Path, **changes: object) -> list[str]:
    """``--config FILE`` of the tests' tiny trial (about 1 s), with ``changes``, and
    ``--quiet``: on a loaded machine the trial may outlast the progress line's interval,
    and these tests count the lines on stderr."""
    path = directory / "trial.json"
    path.write_text(json.dumps({**tiny_config(), **changes}))
    return ["--config", str(path), "--quiet"]


def one_line(capsys: pytest.CaptureFixture[str], command: str) -> str:
    """The single stderr line of a command that ended with status 2."""
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"rmi {command}: "), lines
    return lines[0]


def usage_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """argparse's error line of a rejected option (status 2)."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    return capsys.readouterr().err.splitlines()[-1]


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b"[]", "JSON object, got array"),
        (b"3", "JSON object, got number"),
        (b"null", "JSON object, got null"),
        (b"\xff\xfe{", "not UTF-8 text"),
        (b"[" * 100_000, "nested too deeply"),
    ],
    ids=["list", "number", "null", "not-utf8", "deep"],
)
def test_simulate_refuses_a_config_file_that_is_not_an_object(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, says: str
) -> None:
    config = tmp_path / "config.json"
    config.write_bytes(content)
    out = tmp_path / "out"
    assert main(["simulate", "--config", str(config), "--out", str(out)]) == 2
    line = one_line(capsys, "simulate")
    assert str(config) in line and says in line
    assert not out.exists()


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "--out", "o", "--seed", str(2**70)],
        ["simulate", "--out", "o", "--threads", str(2**40)],
        ["train-wm", "--model", "arx", "--data", "d", "--out", "o", "--seed", str(2**64)],
        ["sweep", "--preset", "tiny", "--out", "o", "--workers", str(2**33)],
    ],
    ids=["seed", "threads", "torch-seed", "workers"],
)
def test_integer_options_beyond_their_range_are_usage_errors(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    argv: list[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    option = next(a for a in argv if a.startswith("--") and argv[argv.index(a) + 1].isdigit())
    line = usage_error(capsys, argv)
    assert f"argument {option}: expected an integer in [" in line
    assert not (tmp_path / "o").exists()


def seed_options(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.Action]]:
    """Every ``--seed`` option of ``parser``'s commands (and their subcommands)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                for where, found in seed_options(sub):
                    yield f"{name} {where}".strip(), found
        elif "--seed" in action.option_strings:
            yield "", action


def test_every_seed_option_takes_the_engine_range() -> None:
    found = dict(seed_options(build_parser()))
    assert {"simulate", "dataset build", "analyze", "control-bench"} <= set(found)
    for command, action in found.items():
        parse = action.type
        assert callable(parse), command
        assert parse(str(SEED_MAX)) == SEED_MAX == 2**63 - 1, command
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(SEED_RANGE)):
            parse(str(SEED_MAX + 1))


def test_simulate_refuses_a_config_seed_beyond_the_engine_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    argv = ["simulate", *tiny_config_file(tmp_path, seed=SEED_MAX + 1), "--out", str(out)]
    assert main(argv) == 2
    line = one_line(capsys, "simulate")
    assert "`seed`" in line and SEED_RANGE in line
    assert not out.exists()


def test_device_cuda_without_a_gpu_is_one_usage_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # also on a GPU machine
    argv = ["train-wm", "--model", "arx", "--data", "d", "--out", str(tmp_path / "o")]
    line = usage_error(capsys, [*argv, "--device", "cuda"])
    assert "argument --device: cuda: CUDA is not available" in line


def grid_file(tmp_path: Path, **changes: object) -> Path:
    g: dict[str, object] = {
        "sizes_cm": [8],
        "porosities": [0.8],
        "hold_forces_N": [20],
        "squeeze_forces_N": [150],
        "seeds": [0],
        "radius_m": 0.01,
    }
    path = tmp_path / "grid.json"
    path.write_text(json.dumps(5 if changes.get("whole") else {**g, **changes}))
    return path


@pytest.mark.parametrize(
    ("changes", "says"),
    [
        ({"whole": True}, "a grid is a JSON object, got number"),
        ({"overrides": 5}, "overrides must be an object"),
        ({"overrides": {"bogus": 1}}, "`bogus`"),
        ({"seeds": [2**70]}, f"seeds must be integers in [0, {2**63 - 1}]"),
        ({"porosities": [[0.5]]}, "porosities must be a list of numbers"),
        ({"overrides_by_size": {"12": {"dt": 0.0025}}}, "overrides_by_size key '12'"),
        ({"overrides_by_size": {"8": {"bogus": 1}}}, "`bogus`"),
    ],
    ids=[
        "number",
        "overrides-number",
        "overrides-unknown",
        "huge-seed",
        "nested-list",
        "by-size-other-size",
        "by-size-unknown",
    ],
)
def test_sweep_refuses_a_bad_grid_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], changes: dict[str, object], says: str
) -> None:
    out = tmp_path / "sweep"
    path = grid_file(tmp_path, **changes)
    assert main(["sweep", "--grid", str(path), "--out", str(out), "--no-progress"]) == 2
    assert says in one_line(capsys, "sweep")
    assert not out.exists()


def test_sweep_index_only_refuses_a_missing_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "nope"
    assert main(["sweep", "--index-only", "--out", str(out)]) == 2
    assert str(out) in one_line(capsys, "sweep")
    assert not out.exists()


def copied_runs(tmp_path: Path, synthetic_runs_dir: Path) -> tuple[Path, Path]:
    """A copy of the synthetic runs to damage, and its first run file."""
    runs = tmp_path / "runs"
    shutil.copytree(synthetic_runs_dir, runs)
    return runs, sorted(runs.rglob("run.parquet"))[0]


def drop_column(path: Path, column: str) -> None:
    """Rewrite a run file without ``column``, keeping its metadata."""
    meta = pl.read_parquet_metadata(path)
    pl.read_parquet(path).drop(column).write_parquet(path, metadata=meta)


@pytest.mark.parametrize("command", ["dataset", "analyze"])
def test_a_run_file_missing_a_column_is_named(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], synthetic_runs_dir: Path, command: str
) -> None:
    runs, bad = copied_runs(tmp_path, synthetic_runs_dir)
    drop_column(bad, "F_meas")
    out = tmp_path / "out"
    argv = ["--runs", str(runs), "--out", str(out)]
    assert main([command, *argv, *(["--bootstrap", "10"] if command == "analyze" else [])]) == 2
    line = one_line(capsys, command)
    assert str(bad) in line and "F_meas" in line
    assert not out.exists()


def forge_seed(path: Path, seed: int) -> None:
    """Rewrite a run file with ``seed`` in its parameters, as a tool other than ``rmi``
    might."""
    meta = pl.read_parquet_metadata(path)
    params = json.loads(meta["rmi.params"])
    meta["rmi.params"] = json.dumps({**params, "seed": seed})
    pl.read_parquet(path).write_parquet(path, metadata=meta)


def test_dataset_names_a_run_file_whose_seed_is_beyond_the_range(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], synthetic_runs_dir: Path
) -> None:
    runs, bad = copied_runs(tmp_path, synthetic_runs_dir)
    forge_seed(bad, SEED_MAX + 1)
    out = tmp_path / "out"
    assert main(["dataset", "build", "--runs", str(runs), "--out", str(out)]) == 2
    line = one_line(capsys, "dataset")
    assert str(bad) in line and "'seed'" in line and SEED_RANGE in line
    assert not out.exists()


def damage_first_row(path: Path) -> None:
    """Rewrite a run file with an infinite load in its first row, keeping its metadata."""
    meta = pl.read_parquet_metadata(path)
    first = pl.int_range(pl.len()) == 0
    expr = pl.when(first).then(float("inf")).otherwise(pl.col("F_meas")).alias("F_meas")
    pl.read_parquet(path).with_columns(expr).write_parquet(path, metadata=meta)


@pytest.mark.parametrize("refused", ["unknown-run-id", "damaged-run-file"])
def test_analyze_refusing_its_input_leaves_no_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], synthetic_runs_dir: Path, refused: str
) -> None:
    runs, bad = copied_runs(tmp_path, synthetic_runs_dir)
    run_id = "size_cm=9/porosity=0.5/F_hold=1/F_squeeze=1/seed=0"
    if refused == "damaged-run-file":
        damage_first_row(bad)
        run_id = bad.parent.relative_to(runs).as_posix()
    out = tmp_path / "figures" / "out"
    argv = ["analyze", "--runs", str(runs), "--out", str(out), "--run-id", run_id]
    assert main([*argv, "--bootstrap", "10"]) == 2
    line = one_line(capsys, "analyze")
    assert (str(bad) if refused == "damaged-run-file" else run_id) in line
    assert not (tmp_path / "figures").exists()


@pytest.mark.parametrize("option", ["--only", "--redo"])
def test_pipeline_with_an_unknown_stage_leaves_no_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str
) -> None:
    out = tmp_path / "out"
    assert main(["pipeline", "--preset", "tiny", "--out", str(out), option, "bogus"]) == 2
    assert "unknown stage 'bogus'" in one_line(capsys, "pipeline")
    assert not out.exists()


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def test_train_wm_names_a_truncated_frames_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], synthetic_dataset_dir: Path
) -> None:
    data = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, data)
    truncate(data / "frames.parquet")
    out = tmp_path / "run"
    assert main(["train-wm", "--model", "arx", "--data", str(data), "--out", str(out)]) == 2
    line = one_line(capsys, "train-wm")
    assert str(data / "frames.parquet") in line and "damaged dataset file" in line
    assert not out.exists()


#: How each training command is started on a dataset, and its output directory's option.
TRAINING = {
    "train-wm": ["train-wm", "--model", "ac-gru"],
    "train-policy": ["train-policy", "--objective", "flow", "--channels", "8,16,32"],
}


@pytest.mark.parametrize(
    ("field", "value", "says"),
    [
        ("z_std", 0.0, "statistics field 'z_std' must be finite and > 0"),
        ("u_mean", float("nan"), "statistics field 'u_mean' must be finite"),
    ],
    ids=["zero-std", "nan-mean"],
)
@pytest.mark.parametrize("command", sorted(TRAINING))
def test_training_names_statistics_that_would_train_on_nan(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    synthetic_dataset_dir: Path,
    command: str,
    field: str,
    value: float,
    says: str,
) -> None:
    """A hand-edited ``stats.json`` of the dataset: one line naming it and the field, and no
    run directory (not a non-finite loss after the run's files were written)."""
    data = tmp_path / "ds"
    shutil.copytree(synthetic_dataset_dir, data)
    stats = json.loads((data / "stats.json").read_text())
    stats[field][0] = value
    (data / "stats.json").write_text(json.dumps(stats))
    out = tmp_path / "run"
    argv = [*TRAINING[command], "--data", str(data), "--out", str(out), "--debug", "--no-progress"]
    assert main(argv) == 2
    line = one_line(capsys, command)
    assert str(data / "stats.json") in line and says in line
    assert not out.exists()


@pytest.mark.parametrize(
    ("model", "arg", "says"),
    [
        ("transformer", "d_model=-5", "transformer: d_model must be a whole number >= 1, got -5"),
        ("transformer", "nhead=7", "transformer: d_model must be a multiple of nhead"),
        ("ac-gru", "hidden=-5", "ac-gru: hidden must be a whole number >= 1, got -5"),
        ("ac-mlp", "hidden=0", "ac-mlp: hidden must be a whole number >= 1, got 0"),
        ("arx", "horizon=-1", "arx: horizon must be a whole number >= 1, got -1"),
    ],
)
def test_train_wm_names_a_model_argument_out_of_range(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    synthetic_dataset_dir: Path,
    model: str,
    arg: str,
    says: str,
) -> None:
    """Every kind of model checks its ``--model-arg`` values the same way, before training."""
    out = tmp_path / "run"
    argv = ["train-wm", "--model", model, "--model-arg", arg, "--data", str(synthetic_dataset_dir)]
    assert main([*argv, "--out", str(out), "--debug", "--no-progress"]) == 2
    assert says in one_line(capsys, "train-wm")
    assert not out.exists()


@pytest.fixture(scope="module")
def trained_run(tmp_path_factory: pytest.TempPathFactory, synthetic_dataset_dir: Path) -> Path:
    """A world-model run of one short epoch (the ARX model: the fastest to train)."""
    out = tmp_path_factory.mktemp("wm") / "arx"
    argv = ["train-wm", "--model", "arx", "--data", str(synthetic_dataset_dir), "--out"]
    assert main([*argv, str(out), "--epochs", "1", "--steps-per-epoch", "2", "--no-progress"]) == 0
    return out


@pytest.mark.parametrize(
    ("damage", "file", "says"),
    [
        ("truncate", "model.safetensors", "damaged weights file"),
        ("[]", "config.json", "JSON object whose 'model' is an object, got array"),
        ('{"model": {"kind": "arx", "bogus": 1}}', "config.json", "cannot build its model"),
    ],
    ids=["truncated-weights", "config-list", "config-unknown-argument"],
)
def test_eval_wm_names_a_damaged_run(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    synthetic_dataset_dir: Path,
    trained_run: Path,
    damage: str,
    file: str,
    says: str,
) -> None:
    run = tmp_path / "run"
    shutil.copytree(trained_run, run)
    if damage == "truncate":
        truncate(run / file)
    else:
        (run / file).write_text(damage)
    out = tmp_path / "tables"
    argv = ["eval-wm", "--runs", str(run), "--data", str(synthetic_dataset_dir), "--out"]
    capsys.readouterr()
    assert main([*argv, str(out), "--split", "train", "--no-latency"]) == 2
    line = one_line(capsys, "eval-wm")
    assert str(run / file) in line and says in line
    assert not out.exists()


def test_simulate_refuses_a_finished_out_unless_overwrite(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "one"
    assert main(["simulate", *tiny_config_file(tmp_path), "--out", str(out)]) == 0
    before = (out / "run.parquet").read_bytes()
    capsys.readouterr()
    other = tiny_config_file(tmp_path, hold_force=30.0)
    assert main(["simulate", *other, "--out", str(out)]) == 2
    assert "--overwrite" in one_line(capsys, "simulate")
    assert (out / "run.parquet").read_bytes() == before
    assert main(["simulate", *other, "--out", str(out), "--overwrite"]) == 0
    assert json.loads((out / "config.json").read_text())["hold_force"] == 30.0


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_simulate_that_cannot_write_names_the_path_and_leaves_nothing(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    code: int,
) -> None:
    """A full disk (or a read-only directory: the tests may run as root, for whom no
    directory is read-only) fails the run file's write; no output of the run is left."""
    import rmi_learn.data.runs as runs

    def refuse(f: object) -> None:
        raise OSError(code, "refused by the test")

    real = runs.atomic_write_bytes
    monkeypatch.setattr(
        runs,
        "atomic_write_bytes",
        lambda path, writer: real(path, refuse if Path(path).name == "run.parquet" else writer),
    )
    out = tmp_path / "one"
    argv = ["simulate", *tiny_config_file(tmp_path), "--out", str(out), "--vtk-every", "50"]
    assert main(argv) == 2
    line = one_line(capsys, "simulate")
    assert str(out / "run.parquet") in line and "refused by the test" in line
    assert not out.exists()


@pytest.mark.parametrize("command", ["sweep", "analyze"])
def test_an_output_directory_that_cannot_be_written_is_named(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    synthetic_runs_dir: Path,
    command: str,
) -> None:
    """A read-only --out (simulated: the tests may run as root) is one line naming it."""
    out = tmp_path / "ro"
    real_mkdir = Path.mkdir

    def mkdir(self: Path, *args: object, **kwargs: object) -> None:
        if self == out:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        real_mkdir(self, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(Path, "mkdir", mkdir)
    argv = {
        "sweep": ["sweep", "--preset", "tiny", "--no-progress", "--out", str(out)],
        "analyze": ["analyze", "--runs", str(synthetic_runs_dir), "--bootstrap", "10"],
    }[command]
    if command == "analyze":
        argv += ["--out", str(out)]
    assert main(argv) == 2
    assert str(out) in one_line(capsys, command)
    assert not out.exists()


#: The documented cap on a JSON file the user names (docs/reliability.md).
MAX_JSON_BYTES = 16 * 1024 * 1024

#: How each command takes a JSON file the user names, and what the file holds.
NAMED_FILES = {
    "train-wm": (["train-wm", "--model", "arx", "--data", "d", "--config"], "config file"),
    "simulate": (["simulate", "--config"], "trial config file"),
    "sweep": (["sweep", "--no-progress", "--grid"], "grid file"),
}


def run_with_deadline(argv: list[str], fifo: Path | None = None) -> int:
    """``main(argv)`` in a thread that must finish within a deadline; a call still waiting
    on the FIFO ``fifo`` then is released (a writer opens and closes it) and fails the test.
    What the call raised is raised here."""
    result: list[Any] = []

    def call() -> None:
        try:
            result.append(main(argv))
        except BaseException as exc:  # handed to the test's thread
            result.append(exc)

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(timeout=60)
    if thread.is_alive() and fifo is not None:
        with open(fifo, "wb"):
            pass
        thread.join(timeout=60)
        pytest.fail(f"{argv[0]} waited for a writer of the FIFO {fifo}")
    assert result, f"{argv[0]} did not finish"
    if isinstance(result[0], BaseException):
        raise result[0]
    return int(result[0])


@pytest.mark.parametrize("kind", ["device", "fifo", "directory", "oversized"])
@pytest.mark.parametrize("command", sorted(NAMED_FILES))
def test_a_named_file_must_be_a_regular_file_within_the_size_limit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, kind: str
) -> None:
    """``/dev/zero`` as a config once ended in a MemoryError and a FIFO waited forever: only
    a regular file of at most 16 MiB is read, and anything else is one line naming it."""
    path = {"device": Path("/dev/zero"), "directory": tmp_path}.get(kind, tmp_path / "f.json")
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "oversized":
        with open(path, "wb") as f:
            f.truncate(MAX_JSON_BYTES + 1)  # sparse: no disk space needed
    argv, what = NAMED_FILES[command]
    out = tmp_path / "out"
    assert run_with_deadline([*argv, str(path), "--out", str(out)], path) == 2
    line = one_line(capsys, command)
    assert str(path) in line and what in line
    if kind == "oversized":
        assert f"{MAX_JSON_BYTES + 1} bytes or more exceed the limit of 16 MiB" in line
    else:
        assert "is not a regular file" in line
    assert not out.exists()


class FullDiskFile(io.RawIOBase):
    """A file on a full disk: every write fails as the system's would."""

    def writable(self) -> bool:
        return True

    def write(self, data: object) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def fill_the_disk(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every write of a file fails with ENOSPC: the atomic writer's file, ``Path.write_*``,
    and polars writing to a path itself (reported by polars as on a real full disk)."""
    import rmi_learn.data.dataset.builder as dataset
    import rmi_learn.data.runs as runs

    real = runs.atomic_write_bytes

    def atomic(path: Path, writer: Any) -> Path:
        return real(path, lambda f: writer(FullDiskFile()))

    monkeypatch.setattr(runs, "atomic_write_bytes", atomic)
    monkeypatch.setattr(dataset, "atomic_write_bytes", atomic)
    monkeypatch.setattr(Path, "write_bytes", lambda self, data: FullDiskFile().write(data))
    monkeypatch.setattr(Path, "write_text", lambda self, *a, **k: FullDiskFile().write(b""))
    real_parquet = pl.DataFrame.write_parquet

    def write_parquet(self: pl.DataFrame, file: Any, *args: Any, **kwargs: Any) -> Any:
        if isinstance(file, (str, os.PathLike)):
            raise pl.exceptions.ComputeError(
                "parquet: File out of specification: underlying IO error: "
                "No space left on device (os error 28)"
            )
        return real_parquet(self, file, *args, **kwargs)

    monkeypatch.setattr(pl.DataFrame, "write_parquet", write_parquet)


def tree(root: Path) -> dict[Path, bytes | None]:
    """Every path under ``root`` with the bytes of the files."""
    return {p.relative_to(root): p.read_bytes() if p.is_file() else None for p in root.rglob("*")}


@pytest.mark.parametrize("existing", [False, True], ids=["new-out", "existing-out"])
@pytest.mark.parametrize("command", ["build", "export"])
def test_dataset_on_a_full_disk_is_one_line_and_leaves_nothing(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    synthetic_runs_dir: Path,
    synthetic_dataset_dir: Path,
    command: str,
    existing: bool,
) -> None:
    """A full disk once ended `dataset build` and `dataset export` in a polars traceback,
    and `build` left an empty --out: now one line naming --out, status 2, no --out that the
    command created, and an --out that existed (a previous build; an empty directory for
    the export) as it was."""
    out = tmp_path / "parent" / "out"
    if existing and command == "build":
        shutil.copytree(synthetic_dataset_dir, out)
    elif existing:
        out.mkdir(parents=True)
    before = tree(tmp_path)
    fill_the_disk(monkeypatch)
    source = ["--runs", str(synthetic_runs_dir)] if command == "build" else ["--data"]
    if command == "export":
        source.append(str(synthetic_dataset_dir))
    assert main(["dataset", command, *source, "--out", str(out)]) == 2
    line = one_line(capsys, "dataset")
    assert str(out) in line and "No space left on device" in line
    assert tree(tmp_path) == before  # hidden temporaries included
