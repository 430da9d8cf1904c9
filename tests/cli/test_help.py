"""Each ``rmi`` command keeps the options it had before the package was laid out by stage:
the same names, defaults and required flags, and ``--help`` lists every visible one."""

from __future__ import annotations

import argparse

import pytest

from rmi_learn.cli import COMMANDS, build_parser, main

#: Command -> option (first spelling; the dest of a positional or subcommand) -> (repr of its
#: default, required), as the command line of commit b0496b8 defined them, plus the options
#: added since (train-wm and train-policy: --tensorboard, --config).
OPTIONS: dict[str, dict[str, tuple[str, bool]]] = {
    "analyze": {
        "--runs": ('None', True),
        "--out": ('None', True),
        "--run-id": ('None', False),
        "--bootstrap": ('2000', False),
        "--seed": ('0', False),
    },
    "closed-loop": {
        "--runs": ('None', True),
        "--chunks": ('None', True),
        "--out": ('None', True),
        "--max-windows": ('4', False),
        "--threads": ('1', False),
        "--no-progress": ('False', False),
    },
    "control-bench": {
        "--runs": ('None', True),
        "--data": ('None', True),
        "--wm": ('None', True),
        "--policy": ('None', True),
        "--out": ('None', True),
        "--states-per-size": ('4', False),
        "--goals-per-state": ('2', False),
        "--setpoints": ('5', False),
        "--k": ('8', False),
        "--receding": ('8', False),
        "--scorers": ('None', False),
        "--goal-kg": ('[]', False),
        "--split": ("'test'", False),
        "--seed": ('0', False),
        "--threads": ('1', False),
        "--no-progress": ('False', False),
    },
    "dataset": {
        "--runs": ('None', False),
        "--out": ('None', False),
        "--seed": ('0', False),
        "dataset_command": ('None', False),
    },
    "distill-policy": {
        "--policy": ('None', True),
        "--dataset": ('None', True),
        "--out": ('None', True),
        "--steps": ('1', False),
        "--epochs": ('20', False),
        "--batch-size": ('64', False),
        "--lr": ('0.0001', False),
        "--max-windows": ('4096', False),
        "--pairs-per-window": ('1', False),
        "--val-windows": ('256', False),
        "--teacher-steps": ('None', False),
        "--weights": ("'model.ema'", False),
        "--seed": ('0', False),
        "--threads": ('None', False),
        "--no-progress": ('False', False),
    },
    "eval-wm": {
        "--runs": ('None', True),
        "--data": ('None', True),
        "--out": ('None', True),
        "--split": ("'test'", False),
        "--batch-size": ('256', False),
        "--max-windows": ('None', False),
        "--threads": ('1', False),
        "--device": ("'cpu'", False),
        "--no-latency": ('False', False),
    },
    "pipeline": {
        "--preset": ('None', False),
        "--config": ('None', False),
        "--out": ('None', True),
        "--threads": ('None', False),
        "--only": ('None', False),
        "--redo": ('None', False),
    },
    "rank": {
        "--data": ('None', True),
        "--wm": ('None', True),
        "--diffusion": ('None', False),
        "--flow": ('None', False),
        "--out": ('None', True),
        "--split": ("'test'", False),
        "--k": ('8', False),
        "--max-windows": ('0', False),
        "--batch-size": ('64', False),
        "--seed": ('0', False),
        "--force-limit": ('400.0', False),
        "--weights": ("'model.ema'", False),
        "--device": ("'cpu'", False),
        "--threads": ('None', False),
    },
    "report": {
        "--out": ('None', True),
        "--validation": ('None', False),
    },
    "simulate": {
        "--config": ('None', False),
        "--out": ('None', True),
        "--vtk-every": ('0', False),
        "--vtk-ascii": ('False', False),
        "--vtk-boundary": ('False', False),
        "--surface": ('False', False),
        "--threads": ('None', False),
        "--overwrite": ('False', False),
        "--size": ('10', False),
        "--porosity": ('0.6', False),
        "--hold": ('40.0', False),
        "--squeeze": ('80.0', False),
        "--radius": ('0.005', False),
        "--seed": ('0', False),
        "--dt": ('None', False),
    },
    "sweep": {
        "--preset": ('None', False),
        "--grid": ('None', False),
        "--out": ('None', True),
        "--backend": ("'local'", False),
        "--workers": ('None', False),
        "--threads-per-run": ('1', False),
        "--retry-failed": ('False', False),
        "--limit": ('None', False),
        "--no-progress": ('False', False),
        "--index-only": ('False', False),
        "--runner": ('None', False),
        "--make-config": ('None', False),
    },
    "train-policy": {
        "--objective": ('None', True),
        "--data": ('None', True),
        "--out": ('None', True),
        "--size-cm": ('None', False),
        "--epochs": ('80', False),
        "--batch-size": ('64', False),
        "--lr": ('0.0001', False),
        "--weight-decay": ('1e-06', False),
        "--patience": ('12', False),
        "--seed": ('0', False),
        "--history": ('16', False),
        "--horizon": ('32', False),
        "--ema-decay": ('0.999', False),
        "--snr-floor": ('0.0', False),
        "--val-windows": ('1024', False),
        "--device": ("'cpu'", False),
        "--threads": ('None', False),
        "--max-steps-per-epoch": ('None', False),
        "--resume": ('False', False),
        "--debug": ('False', False),
        "--deterministic": ('False', False),
        "--no-progress": ('False', False),
        "--channels": ('(64, 128, 256)', False),
        "--tensorboard": ('False', False),
        "--config": ('None', False),
        "--wm": ('None', False),
    },
    "train-wm": {
        "--model": ('None', True),
        "--data": ('None', True),
        "--out": ('None', True),
        "--size": ('None', False),
        "--state-groups": ("'ALL'", False),
        "--shuffle-actions": ('False', False),
        "--model-arg": ('[]', False),
        "--epochs": ('40', False),
        "--patience": ('8', False),
        "--tf-epochs": ('20', False),
        "--water-weight": ('None', False),
        "--huber-delta": ('1.0', False),
        "--loss-scale": ('None', False),
        "--batch-size": ('128', False),
        "--steps-per-epoch": ('None', False),
        "--lr": ('None', False),
        "--val-windows": ('4096', False),
        "--seed": ('0', False),
        "--deterministic": ('False', False),
        "--device": ("'cpu'", False),
        "--threads": ('1', False),
        "--resume": ('False', False),
        "--debug": ('False', False),
        "--no-progress": ('False', False),
        "--tensorboard": ('False', False),
        "--config": ('None', False),
    },
}


def _actions(command: str) -> dict[str, argparse.Action]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {
        (a.option_strings[0] if a.option_strings else a.dest): a
        for a in sub.choices[command]._actions
        if not isinstance(a, argparse._HelpAction)
    }


def test_every_command_is_there() -> None:
    assert sorted(COMMANDS) == sorted(OPTIONS)


@pytest.mark.parametrize("command", sorted(OPTIONS))
def test_options_keep_their_names_and_defaults(command: str) -> None:
    actions = _actions(command)
    assert list(actions) == list(OPTIONS[command])
    for name, (default, required) in OPTIONS[command].items():
        assert (repr(actions[name].default), actions[name].required) == (default, required), name


@pytest.mark.parametrize("command", sorted(OPTIONS))
def test_help_lists_the_options(command: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main([command, "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    for name, action in _actions(command).items():
        if action.help != argparse.SUPPRESS and name.startswith("--"):
            assert name in text, name
