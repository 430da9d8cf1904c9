"""``--config FILE`` of ``rmi train-wm`` and ``rmi train-policy``: the file's options, the
command line's precedence over them, and one line naming the key for a bad one."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import pytest

from rmi_learn.cli import _with_options_file, build_parser, main


def parse(argv: list[str]) -> Any:
    """The namespace ``rmi`` parses ``argv`` into, with the config file applied."""
    parser = build_parser()
    return parser.parse_args(_with_options_file(parser, argv))


def write(tmp_path: Path, options: Any, name: str = "options.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(options))
    return path


def test_the_file_sets_options_and_the_command_line_overrides_them(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        {
            "model": "ac-gru",
            "data": "ds",
            "epochs": 5,
            "batch_size": 32,
            "lr": 1,
            "shuffle-actions": True,
            "debug": False,
            "model-arg": {"hidden": 16, "dropout": 0.5},
            "size": None,
            "state-groups": "LS",
        },
    )
    args = parse(["train-wm", "--config", str(path), "--out", "o", "--epochs", "7"])
    assert (args.model, args.data, args.out) == ("ac-gru", "ds", "o")
    assert args.epochs == 7  # the command line wins
    assert (args.batch_size, args.lr, args.shuffle_actions, args.debug) == (32, 1.0, True, False)
    assert args.model_arg == ["hidden=16", "dropout=0.5"]
    assert (args.size, args.state_groups) == (None, "LS")
    # Order does not matter: the option before --config wins as well.
    assert (
        parse(["train-wm", "--batch-size", "8", "--config", str(path), "--out", "o"]).batch_size
        == 8
    )
    # A repeatable option adds the command line's entries after the file's.
    args = parse(["train-wm", f"--config={path}", "--out", "o", "--model-arg", "hidden=64"])
    assert args.model_arg == ["hidden=16", "dropout=0.5", "hidden=64"]


def test_train_policy_takes_lists_and_required_options_from_the_file(tmp_path: Path) -> None:
    path = write(
        tmp_path, {"objective": "flow", "data": "ds", "out": "o", "channels": [8, 16], "lr": 3e-4}
    )
    args = parse(["train-policy", "--config", str(path)])
    assert (args.objective, args.data, args.out) == ("flow", Path("ds"), Path("o"))
    assert (args.channels, args.lr) == ((8, 16), 3e-4)
    args = parse(
        ["train-policy", "--config", str(path), "--channels", "16,32", "--objective", "diffusion"]
    )
    assert (args.channels, args.objective) == ((16, 32), "diffusion")


def test_an_option_of_several_values_takes_a_list_or_one_value(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = {"model": "ac-gru", "data": "ds", "out": "o", "observation-mode": "sensors"}
    args = parse(
        ["train-wm", "--config", str(write(tmp_path, {**base, "val-phases": ["squeeze", "lift"]}))]
    )
    assert (args.val_phases, args.observation_mode) == (["squeeze", "lift"], "sensors")
    args = parse(["train-wm", "--config", str(write(tmp_path, {**base, "val_phases": "squeeze"}))])
    assert args.val_phases == ["squeeze"]
    bad = write(tmp_path, {**base, "val-phases": ["squeeze", "done"]})
    assert main(["train-wm", "--config", str(bad)]) == 2
    assert "'val-phases' must be one of" in capsys.readouterr().err


@pytest.mark.skipif(sys.version_info < (3, 11), reason="tomllib needs Python 3.11")
def test_a_toml_file(tmp_path: Path) -> None:
    path = tmp_path / "options.toml"
    path.write_text('model = "arx"\ndata = "ds"\nepochs = 3\ndebug = true\n')
    args = parse(["train-wm", "--config", str(path), "--out", "o"])
    assert (args.model, args.epochs, args.debug) == ("arx", 3, True)


@pytest.mark.parametrize(
    ("command", "options", "says"),
    [
        ("train-wm", {"epoch": 3}, "unknown option 'epoch'; accepted: batch-size,"),
        ("train-wm", {"config": "other.json"}, "unknown option 'config'"),
        ("train-wm", {"epochs": "5"}, "'epochs' expects a number, got string '5'"),
        ("train-wm", {"epochs": 4.5}, "'epochs': expected an integer in [1, "),
        ("train-wm", {"epochs": 0}, "'epochs': expected an integer in [1, "),
        ("train-wm", {"lr": -1}, "'lr': expected a finite number in (0, inf]"),
        ("train-wm", {"debug": 1}, "'debug' is a flag: expected true or false, got number"),
        ("train-wm", {"data": 3}, "'data' expects a string, got number"),
        ("train-wm", {"model": "gru"}, "'model' must be one of 'baseline',"),
        ("train-wm", {"size": 9}, "'size' must be one of 8, 10, 12, got 9"),
        ("train-wm", {"epochs": None}, "'epochs' has no 'none' value"),
        ("train-wm", {"model-arg": 3}, "'model-arg' expects a list, got number"),
        ("train-policy", {"channels": [64, "x"]}, "'channels' expects a list of integers"),
        ("train-policy", {"objective": ["flow"]}, "'objective' expects a string, got array"),
        ("train-policy", [1, 2], "expected a JSON object of options, got array"),
    ],
)
def test_a_bad_key_or_value_is_one_line_naming_it(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    command: str,
    options: Any,
    says: str,
) -> None:
    path = write(tmp_path, options)
    out = tmp_path / "run"
    argv = [command, "--config", str(path), "--data", "ds", "--out", str(out)]
    argv += ["--model", "ac-gru"] if command == "train-wm" else ["--objective", "flow"]
    assert main(argv) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"rmi {command}: --config {path}: ") and says in lines[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("content", "says"),
    [("{", "not valid JSON"), (None, "cannot read it")],
    ids=["json", "missing"],
)
def test_an_unreadable_file_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None, says: str
) -> None:
    path = tmp_path / "options.json"
    if content is not None:
        path.write_text(content)
    assert main(["train-wm", "--config", str(path), "--out", str(tmp_path / "run")]) == 2
    line = capsys.readouterr().err.strip()
    assert "\n" not in line and str(path) in line and says in line


def test_a_training_run_records_the_merged_options(
    tmp_path: Path, synthetic_dataset_dir: Path
) -> None:
    path = write(
        tmp_path,
        {
            "model": "ac-mlp",
            "data": str(synthetic_dataset_dir),
            "epochs": 2,
            "seed": 5,
            "debug": True,
            "no-progress": True,
            "model-arg": {"hidden": 16},
        },
    )
    out = tmp_path / "run"
    assert main(["train-wm", "--config", str(path), "--out", str(out), "--epochs", "1"]) == 0
    config = json.loads((out / "config.json").read_text())
    assert config["train"]["epochs"] == 1  # from the command line
    assert config["extra"]["seed"] == 5 and config["extra"]["debug"] is True  # from the file
    assert config["model"]["hidden"] == 16


def test_config_without_a_value_is_the_commands_usage_error(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as done:
        main(["train-wm", "--model", "arx", "--data", "ds", "--out", "o", "--config"])
    assert done.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: rmi train-wm") and "--config: expected one argument" in err
