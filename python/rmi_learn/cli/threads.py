"""The ``--threads`` option every ``rmi`` command shares, and the thread count it stands
for (``$RMI_NUM_THREADS``, else every core this process may use, when it is absent)."""

from __future__ import annotations

import argparse
import os

from rmi_learn.errors import InputError
from rmi_learn.option_types import count


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one,
    else every core)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # macOS and Windows have no affinity call
        return os.cpu_count() or 1


#: The environment variable the engine reads for its default thread count; the ``rmi``
#: commands read it too, so that one setting covers the engine and torch.
THREADS_ENV = "RMI_NUM_THREADS"


def add_threads(parser: argparse.ArgumentParser, uses: str) -> None:
    """The ``--threads N`` option every command shares: the CPU threads the command works
    with in total, ``uses`` saying on what; absent means ``$RMI_NUM_THREADS``, else every
    core available (:func:`threads_of`)."""
    parser.add_argument(
        "--threads",
        type=count(1),
        default=None,
        metavar="N",
        help=f"CPU threads for {uses} (default: ${THREADS_ENV}, else every core this process "
        "may use)",
    )


def threads_of(value: int | None) -> int:
    """The thread count a ``--threads`` value stands for: ``value``; when the option was not
    given, ``$RMI_NUM_THREADS`` (the engine's own default) or else every core available.
    Raises :class:`~rmi_learn.errors.InputError` for a set variable that is not a count."""
    if value is not None:
        return value
    text = os.environ.get(THREADS_ENV, "").strip()
    if not text:
        return available_cores()
    try:
        return count(1)(text)
    except argparse.ArgumentTypeError as exc:
        raise InputError(f"{THREADS_ENV}: {exc} (worker threads), or unset it") from None
