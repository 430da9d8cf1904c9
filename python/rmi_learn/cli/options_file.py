"""``--config FILE``: a command's options from a JSON (or, on Python 3.11+, TOML) file.

A command opts in with ``OPTIONS_FILE = True`` in its module and a ``--config`` option added
by :func:`add_config_option`. The file is an object whose keys are the command's long option
names, with or without the dashes (``"batch-size"`` or ``"batch_size"``), and whose values
are JSON values of the option's kind: a number, a string, ``true``/``false`` for a flag,
``null`` for an option whose default is "none", a list for a repeatable option or for a
comma-separated one (``"channels": [64, 128, 256]``) and, for ``--model-arg``, an object
(``{"d_model": 128}``).

:func:`expand` reads the file before the command line is parsed and inserts the equivalent
options right after the command name, so that argparse parses them first: an option given
on the command line comes later and wins, the file's values pass the same checks as typed
ones, and an option the command requires may come from the file. An unknown key or a value
of the wrong kind ends the command with one line naming the file and the key (exit status
2), before anything runs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, NoReturn

from rmi_learn.errors import InputError
from rmi_learn.option_types import counts
from rmi_learn.user_files import read_user_text

#: Keys a file may not set: the file itself and the help.
_EXCLUDED = frozenset({"config", "help"})


def add_config_option(parser: argparse.ArgumentParser) -> None:
    """Add ``--config FILE`` to a command's ``parser`` (see the module docstring)."""
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        metavar="FILE",
        help="JSON file of this command's options (keys: option names, e.g. "
        '{"epochs": 20, "batch-size": 64}); options given here override it',
    )


def config_path(argv: list[str]) -> Path | None:
    """The ``--config`` value among a command's arguments ``argv`` (without the command
    name), as argparse would read it (``--config F``, ``--config=F``, the last one wins)."""
    pre = _QuietParser(add_help=False)
    pre.add_argument("--config", type=Path, default=None)
    try:
        known, _ = pre.parse_known_args(argv)
    except _Unparsable:
        return None  # `--config` without a value: the command's own parser says so
    path: Path | None = known.config
    return path


class _Unparsable(Exception):
    pass


class _QuietParser(argparse.ArgumentParser):
    """A parser that raises instead of printing a usage message and exiting."""

    def error(self, message: str) -> NoReturn:
        raise _Unparsable(message)


def read_options(path: Path) -> dict[str, Any]:
    """The object in the JSON (or ``.toml``) file ``path``; InputError naming the file for
    one that is missing, not a regular file, too long (see
    :func:`~rmi_learn.user_files.read_user_text`), not text, not parseable or not an object."""
    from rmi_learn.data.runs import json_kind

    try:
        text = read_user_text(path, "config file", label=f"--config {path}")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"--config {path}: cannot read it ({exc})") from exc
    data: Any
    if path.suffix.lower() == ".toml":
        if sys.version_info >= (3, 11):
            import tomllib

            try:
                data = tomllib.loads(text)
            except tomllib.TOMLDecodeError as exc:
                raise InputError(f"--config {path}: not valid TOML: {exc}") from exc
        else:
            raise InputError(f"--config {path}: TOML needs Python 3.11 or later; use JSON")
    else:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(f"--config {path}: not valid JSON: {exc}") from exc
        except RecursionError:
            raise InputError(f"--config {path}: JSON nested too deeply") from None
    if not isinstance(data, dict):
        raise InputError(
            f"--config {path}: expected a JSON object of options, got {json_kind(data)}"
        )
    return data


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """Long option name without dashes -> action, for every option a file may set."""
    out: dict[str, argparse.Action] = {}
    for action in parser._actions:
        for flag in action.option_strings:
            if flag.startswith("--") and flag[2:] not in _EXCLUDED:
                out[flag[2:]] = action
    return out


def _kind(value: Any) -> str:
    from rmi_learn.data.runs import json_kind

    return json_kind(value)


def _scalar_text(action: argparse.Action, key: str, value: Any, where: str) -> str:
    """The command-line text of one value of ``action``, checked as argparse checks typed
    text (so a message names the accepted range), and refused when its JSON kind differs
    from what the option parses to (``"epochs": "5"``, ``"data": 5``)."""
    text = value if isinstance(value, str) else json.dumps(value)
    converted: Any = text
    if action.type is not None:
        convert: Any = action.type
        try:
            converted = convert(text)
        except (argparse.ArgumentTypeError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: {key!r}: {exc}") from None
    numeric = isinstance(converted, (int, float)) and not isinstance(converted, bool)
    if numeric and not (isinstance(value, (int, float)) and not isinstance(value, bool)):
        raise InputError(f"{where}: {key!r} expects a number, got {_kind(value)} {value!r}")
    if not numeric and not isinstance(value, str):
        raise InputError(f"{where}: {key!r} expects a string, got {_kind(value)}")
    if action.choices is not None and converted not in action.choices:
        choices = ", ".join(repr(c) for c in action.choices)
        raise InputError(f"{where}: {key!r} must be one of {choices}, got {value!r}")
    return text


def _tokens(action: argparse.Action, key: str, value: Any, where: str) -> list[str]:
    """The command-line options equivalent to ``key: value``."""
    flag = next(f for f in action.option_strings if f.startswith("--"))
    if action.nargs == 0:  # a flag (store_true)
        if not isinstance(value, bool):
            raise InputError(
                f"{where}: {key!r} is a flag: expected true or false, got {_kind(value)}"
            )
        return [flag] if value == action.const else []
    if value is None:
        if action.default is not None:
            raise InputError(f"{where}: {key!r} has no 'none' value; remove the key instead")
        return []
    if isinstance(action, argparse._AppendAction):
        if isinstance(value, dict):  # --model-arg: {"d_model": 128} -> d_model=128
            value = [f"{k}={json.dumps(v)}" for k, v in value.items()]
        if not isinstance(value, list):
            raise InputError(f"{where}: {key!r} expects a list, got {_kind(value)}")
        return [f"{flag}={_scalar_text(action, key, v, where)}" for v in value]
    if action.nargs in ("+", "*"):  # --val-phases squeeze lift: a list or one value
        values = value if isinstance(value, list) else [value]
        if not values and action.nargs == "+":
            raise InputError(f"{where}: {key!r} expects at least one value")
        return [flag, *(_scalar_text(action, key, v, where) for v in values)]
    if isinstance(value, list) and action.type is counts:  # comma-separated: --channels
        if not value or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
            raise InputError(f"{where}: {key!r} expects a list of integers")
        value = ",".join(str(v) for v in value)
    return [f"{flag}={_scalar_text(action, key, value, where)}"]


def options_to_argv(
    parser: argparse.ArgumentParser, options: dict[str, Any], where: str
) -> list[str]:
    """The command-line options that ``options`` (a parsed config file) stands for, checked
    against the options of ``parser``; ``where`` names the file in messages."""
    known = _options(parser)
    argv: list[str] = []
    for raw, value in options.items():
        key = str(raw)
        action = known.get(key.replace("_", "-"))
        if action is None or key.startswith("-"):
            accepted = ", ".join(sorted(known))
            raise InputError(f"{where}: unknown option {key!r}; accepted: {accepted}")
        argv += _tokens(action, key, value, where)
    return argv


def expand(command_parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``argv`` (the command's arguments, without its name) with the options of its
    ``--config`` file inserted in front, so that the command line overrides them; ``argv``
    unchanged without ``--config``."""
    path = config_path(argv)
    if path is None:
        return argv
    where = f"--config {path}"
    return options_to_argv(command_parser, read_options(path), where) + argv
