"""Each ``rmi`` command keeps the options recorded here (names, defaults, required flags:
a change is deliberate and updates this table), ``--help`` lists every visible one with
its default, and ``--threads`` means the same on every command."""

from __future__ import annotations

import argparse

import pytest

from rmi_learn.cli import COMMANDS, build_parser, main

#: Command -> option (first spelling; the dest of a positional or subcommand) -> (repr of its
#: default, required). The command line of commit b0496b8 defined them; since then
#: ``--threads`` defaults to every core on every command (sweep gained it), simulate
#: gained ``--quiet``, ``view`` was added, train-wm and train-policy gained
#: ``--tensorboard`` and ``--config``, train-policy ``--wm``, closed-loop lost
#: ``--command``, and control-bench gained ``--replace-other``.
OPTIONS: dict[str, dict[str, tuple[str, bool]]] = {
    "analyze": {
        "--runs": ("None", True),
        "--out": ("None", True),
        "--run-id": ("None", False),
        "--bootstrap": ("2000", False),
        "--seed": ("0", False),
    },
    "closed-loop": {
        "--runs": ("None", True),
        "--chunks": ("None", True),
        "--out": ("None", True),
        "--max-windows": ("4", False),
        "--threads": ("None", False),
        "--no-progress": ("False", False),
    },
    "control-bench": {
        "--runs": ("None", True),
        "--data": ("None", False),
        "--wm": ("None", False),
        "--policy": ("None", False),
        "--out": ("None", True),
        "--protocol": ("None", False),
        "--workers": ("1", False),
        "--replace-other": ("False", False),
        "--states-per-size": ("4", False),
        "--goals-per-state": ("2", False),
        "--setpoints": ("5", False),
        "--k": ("8", False),
        "--receding": ("8", False),
        "--scorers": ("None", False),
        "--no-ensemble": ("False", False),
        "--receding-scorers": ("()", False),
        "--refine-scorers": ("()", False),
        "--refine-metrics": ("('smooth',)", False),
        "--controllers": ("None", False),
        "--sizes": ("None", False),
        "--goal-kg": ("[]", False),
        "--split": ("'test'", False),
        "--seed": ("0", False),
        "--threads": ("None", False),
        "--no-progress": ("False", False),
    },
    "dataset": {
        "--runs": ("None", False),
        "--out": ("None", False),
        "--seed": ("0", False),
        "dataset_command": ("None", False),
    },
    "distill-policy": {
        "--policy": ("None", True),
        "--dataset": ("None", True),
        "--out": ("None", True),
        "--steps": ("1", False),
        "--epochs": ("20", False),
        "--batch-size": ("64", False),
        "--lr": ("0.0001", False),
        "--max-windows": ("4096", False),
        "--pairs-per-window": ("1", False),
        "--val-windows": ("256", False),
        "--teacher-steps": ("None", False),
        "--weights": ("'model.ema'", False),
        "--seed": ("0", False),
        "--threads": ("None", False),
        "--no-progress": ("False", False),
    },
    "eval-wm": {
        "--runs": ("None", True),
        "--data": ("None", True),
        "--out": ("None", True),
        "--split": ("'test'", False),
        "--batch-size": ("256", False),
        "--max-windows": ("None", False),
        "--threads": ("None", False),
        "--device": ("'cpu'", False),
        "--no-latency": ("False", False),
    },
    "pipeline": {
        "--preset": ("None", False),
        "--config": ("None", False),
        "--out": ("None", True),
        "--threads": ("None", False),
        "--only": ("None", False),
        "--redo": ("None", False),
    },
    "rank": {
        "--data": ("None", True),
        "--wm": ("None", True),
        "--diffusion": ("None", False),
        "--flow": ("None", False),
        "--out": ("None", True),
        "--split": ("'test'", False),
        "--k": ("8", False),
        "--max-windows": ("0", False),
        "--batch-size": ("64", False),
        "--seed": ("0", False),
        "--force-limit": ("400.0", False),
        "--weights": ("'model.ema'", False),
        "--device": ("'cpu'", False),
        "--threads": ("None", False),
    },
    "report": {
        "--out": ("None", True),
        "--validation": ("None", False),
    },
    "simulate": {
        "--config": ("None", False),
        "--out": ("None", True),
        "--vtk-every": ("0", False),
        "--vtk-ascii": ("False", False),
        "--vtk-boundary": ("False", False),
        "--surface": ("False", False),
        "--threads": ("None", False),
        "--overwrite": ("False", False),
        "--quiet": ("False", False),
        "--size": ("10", False),
        "--porosity": ("0.6", False),
        "--hold": ("40.0", False),
        "--squeeze": ("80.0", False),
        "--radius": ("0.005", False),
        "--seed": ("0", False),
        "--dt": ("None", False),
    },
    "sweep": {
        "--preset": ("None", False),
        "--grid": ("None", False),
        "--out": ("None", True),
        "--backend": ("'local'", False),
        "--threads": ("None", False),
        "--workers": ("None", False),
        "--threads-per-run": ("1", False),
        "--retry-failed": ("False", False),
        "--limit": ("None", False),
        "--no-progress": ("False", False),
        "--index-only": ("False", False),
        "--runner": ("None", False),
        "--make-config": ("None", False),
    },
    "train-policy": {
        "--objective": ("None", True),
        "--data": ("None", True),
        "--out": ("None", True),
        "--size-cm": ("None", False),
        "--epochs": ("80", False),
        "--batch-size": ("64", False),
        "--lr": ("0.0001", False),
        "--weight-decay": ("1e-06", False),
        "--patience": ("12", False),
        "--seed": ("0", False),
        "--history": ("16", False),
        "--horizon": ("32", False),
        "--ema-decay": ("0.999", False),
        "--snr-floor": ("0.0", False),
        "--val-windows": ("1024", False),
        "--device": ("'cpu'", False),
        "--threads": ("None", False),
        "--max-steps-per-epoch": ("None", False),
        "--resume": ("False", False),
        "--debug": ("False", False),
        "--deterministic": ("False", False),
        "--no-progress": ("False", False),
        "--channels": ("(64, 128, 256)", False),
        "--tensorboard": ("False", False),
        "--config": ("None", False),
        "--wm": ("None", False),
    },
    "train-wm": {
        "--model": ("None", True),
        "--data": ("None", True),
        "--out": ("None", True),
        "--size": ("None", False),
        "--state-groups": ("'ALL'", False),
        "--shuffle-actions": ("False", False),
        "--observation-mode": ("'privileged'", False),
        "--sensors": ("None", False),
        "--model-arg": ("[]", False),
        "--horizon": ("None", False),
        "--epochs": ("40", False),
        "--patience": ("8", False),
        "--tf-epochs": ("20", False),
        "--water-weight": ("None", False),
        "--huber-delta": ("1.0", False),
        "--loss-scale": ("None", False),
        "--batch-size": ("128", False),
        "--steps-per-epoch": ("None", False),
        "--lr": ("None", False),
        "--val-windows": ("4096", False),
        "--val-phases": ("None", False),
        "--seed": ("0", False),
        "--deterministic": ("False", False),
        "--device": ("'cpu'", False),
        "--threads": ("None", False),
        "--resume": ("False", False),
        "--debug": ("False", False),
        "--no-progress": ("False", False),
        "--tensorboard": ("False", False),
        "--config": ("None", False),
    },
    "view": {
        "runs": ("None", True),
        "--rrd": ("None", True),
        "--every": ("1", False),
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


def _visible(command: str) -> list[argparse.Action]:
    return [
        a
        for a in _actions(command).values()
        if a.help != argparse.SUPPRESS and not isinstance(a, argparse._SubParsersAction)
    ]


@pytest.mark.parametrize("command", sorted(OPTIONS))
def test_every_option_says_what_it_is_and_its_default(
    command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    from rmi_learn.cli.helpformat import shown_default

    with pytest.raises(SystemExit):
        main([command, "--help"])
    # argparse wraps help text at the terminal width: compare without the line breaks.
    text = " ".join(capsys.readouterr().out.split())
    for action in _visible(command):
        name = action.option_strings[0] if action.option_strings else action.dest
        assert action.help, f"{command} {name} has no help text"
        valued = action.default not in (None, False, [], argparse.SUPPRESS)
        if not action.option_strings or action.required or not valued:
            continue
        if "default" in action.help:  # the help names its default in its own words
            continue
        assert f"(default: {shown_default(action.default)})" in text, (command, name)


def test_defaults_in_help_are_written_as_typed() -> None:
    from rmi_learn.cli.helpformat import DefaultsHelpFormatter

    parser = argparse.ArgumentParser(prog="x", formatter_class=DefaultsHelpFormatter)
    parser.add_argument("--widths", default=(64, 128), help="widths")
    parser.add_argument("--pct", default="5%", help="share")
    parser.add_argument("--flag", action="store_true", help="a flag")
    parser.add_argument("--opt", default=None, help="absent: nothing")
    parser.add_argument("--need", required=True, default="x", help="required")
    parser.add_argument("--own", default=3, help="says it (default: three)")
    text = " ".join(parser.format_help().split())
    assert "widths (default: 64,128)" in text and "share (default: 5%)" in text
    assert "a flag --opt" in text and "absent: nothing --need" in text
    assert "required --own" in text and "(default: three)" in text
    assert "(default: None)" not in text and "(default: False)" not in text


def test_threads_means_the_same_on_every_command() -> None:
    """One convention: every command has ``--threads N``, an integer >= 1 whose absence
    means every core this process may use, and says what the threads run."""
    for command in sorted(OPTIONS):
        if command in ("analyze", "dataset", "report", "view"):
            continue  # single-threaded stages
        action = _actions(command)["--threads"]
        assert action.default is None and action.metavar == "N", command
        assert action.help is not None
        assert action.help.endswith(
            "(default: $RMI_NUM_THREADS, else every core this process may use)"
        ), command
        assert callable(action.type) and action.type("1") == 1


def test_threads_default_is_the_engines(monkeypatch: pytest.MonkeyPatch) -> None:
    """Absent ``--threads`` means what the engine's default means: ``$RMI_NUM_THREADS``,
    else every available core; a bad variable is an input error naming it."""
    from rmi_learn.cli.threads import available_cores, threads_of
    from rmi_learn.errors import InputError

    monkeypatch.delenv("RMI_NUM_THREADS", raising=False)
    assert threads_of(3) == 3
    assert threads_of(None) == available_cores() >= 1
    monkeypatch.setenv("RMI_NUM_THREADS", " 5 ")
    assert threads_of(None) == 5 and threads_of(2) == 2
    for bad in ("lots", "0"):
        monkeypatch.setenv("RMI_NUM_THREADS", bad)
        with pytest.raises(InputError, match="RMI_NUM_THREADS: expected an integer"):
            threads_of(None)


def test_sweep_fills_threads_with_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    """``rmi sweep --threads N --threads-per-run K`` runs N // K workers (at least 1)."""
    import rmi_learn.data.sweep as sweep_lib

    seen: list[object] = []

    class Done:
        def summary(self) -> str:
            return "done"

    def fake_sweep(out: str, **kw: object) -> Done:
        seen.append(kw["workers"])
        return Done()

    monkeypatch.setattr(sweep_lib, "sweep", fake_sweep)
    base = ["sweep", "--preset", "tiny", "--out", "o"]
    assert main([*base, "--threads", "8", "--threads-per-run", "2"]) == 0
    assert main([*base, "--threads", "1", "--threads-per-run", "2"]) == 0
    assert main([*base, "--threads", "8", "--workers", "3"]) == 0
    assert main([*base, "--backend", "ray"]) == 0
    assert seen == [4, 1, 3, None]


def test_help_texts_name_things_not_paper_numbers(capsys: pytest.CaptureFixture[str]) -> None:
    """A user without the paper reads what a table or figure holds, not its number there."""
    with pytest.raises(SystemExit):
        main(["--help"])
    texts = [capsys.readouterr().out]
    for command in sorted(OPTIONS):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        texts.append(capsys.readouterr().out)
    import re

    for text in texts:
        assert not re.search(r"\b(Tables?|Figs?\.|Eq\.) ?[0-9IVXS]", text), text
        assert "the paper" not in text, text
