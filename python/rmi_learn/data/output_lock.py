"""A command's hold on its output directory: an exclusive lock for the command's duration
(:func:`output_lock`), so that two runs of one command never write one directory at once.

The commands that rewrite a whole file of results as they go (``rmi sweep``'s index,
``rmi closed-loop``'s and ``rmi control-bench``'s checkpoints) would otherwise lose the
rows of one run to the other's next rewrite."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from rmi_learn.errors import StageFailure

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no lock
    fcntl = None  # type: ignore[assignment]


def lock_file(command: str) -> str:
    """Name of the lock file of ``command`` in its output directory: ``.<command>.lock``."""
    return f".{command}.lock"


@contextlib.contextmanager
def output_lock(out: Path, command: str) -> Iterator[None]:
    """Exclusive lock on ``OUT/.<command>.lock`` while the block runs; raises
    :class:`~rmi_learn.errors.StageFailure` naming the lock when another process holds it.
    The kernel drops the lock when its holder dies, even by kill -9, so a killed run never
    blocks the next one."""
    path = out / lock_file(command)
    f = open(path, "a+b")  # noqa: SIM115 - held for the whole block
    try:
        if fcntl is not None:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as exc:
                raise StageFailure(f"another {command} is writing {out} (lock {path})") from exc
        yield
    finally:
        f.close()


__all__ = ["lock_file", "output_lock"]
