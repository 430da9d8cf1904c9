"""The errors a stage of ``rmi_learn`` reports to its caller, and which of them are the
user's: the ``rmi`` commands and the pipeline end on those with one line and exit status 2,
where a bug keeps its traceback."""

from __future__ import annotations

import contextlib
import errno
import json
import sys
import unicodedata
from types import TracebackType

import rmi_sph


class InputError(Exception):
    """The user's input is wrong (an option, a file, a directory of the wrong kind): the
    ``rmi`` entry point prints ``rmi COMMAND: message`` and exits with status 2, the same as
    for the input errors :func:`is_input_error` recognises by type."""


class StageFailure(Exception):
    """A stage ran on valid input but could not finish (another sweep holds the output
    directory, an optional backend is missing): ``rmi COMMAND: message`` and exit status 1."""


class RunFileError(ValueError):
    """A run file's columns, values or metadata break the run-file contract."""


class input_errors(contextlib.ContextDecorator):
    """Re-raise the given exception types as :class:`InputError` with the same message, for
    a stage whose library calls report bad input with built-in types (``ValueError`` for a
    value, ``OSError`` for a directory). Use as ``with input_errors(ValueError): ...`` or as
    a decorator."""

    def __init__(self, *types: type[BaseException]) -> None:
        self.types = types

    def __enter__(self) -> input_errors:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc is not None and isinstance(exc, self.types) and not isinstance(exc, InputError):
            raise InputError(exc) from exc


#: OS error numbers that say the output cannot be written where the user asked (a full disk
#: or quota, a read-only file system, a name too long): the user's to fix, not a bug.
OUTPUT_ERRNOS: frozenset[int] = frozenset(
    {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.ENAMETOOLONG}
)


def is_input_error(exc: BaseException) -> bool:
    """Whether ``exc`` says the user's input is wrong (a path that is missing or unreadable,
    an output directory that cannot be written, a file that is not JSON, a damaged run
    file, a config value out of range, or an :class:`InputError` a stage raised for what it
    caught) rather than that the code is. This is the one place that decides which errors
    end a command with status 2."""
    paths = (FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError)
    inputs = (PermissionError, json.JSONDecodeError, RunFileError, rmi_sph.ConfigError, InputError)
    if isinstance(exc, OSError) and exc.errno in OUTPUT_ERRNOS:
        return True
    return isinstance(exc, (*paths, *inputs))


def exit_status(exc: BaseException) -> int | None:
    """The exit status a command ends with when ``exc`` escapes it: 130 for Ctrl-C, 2 for
    an input error, 1 for a :class:`StageFailure`; ``None`` for a bug (re-raise it)."""
    if isinstance(exc, KeyboardInterrupt):
        return 130
    if isinstance(exc, StageFailure):
        return 1
    if isinstance(exc, Exception) and is_input_error(exc):
        return 2
    return None


def report(command: str, exc: BaseException) -> int | None:
    """Print ``rmi COMMAND: message`` for an ``exc`` that ends ``command`` with a status
    (see :func:`exit_status`) and return that status; ``None`` (nothing printed) for a bug."""
    status = exit_status(exc)
    if status is not None:
        text = "interrupted" if status == 130 else one_line(str(exc))
        print(f"rmi {command}: {text}", file=sys.stderr)
    return status


def one_line(text: str) -> str:
    """``text`` with its control characters escaped (a line break as ``\\n``): a message
    that quotes the user's input (a config key with a line break in it) stays one line."""
    return "".join(repr(c)[1:-1] if unicodedata.category(c) == "Cc" else c for c in text)
