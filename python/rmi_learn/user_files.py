"""Bounded reading of the files a user names on the command line (``--config``, ``--grid``):
only a regular file of at most a stated size is read, so that a device (``/dev/zero``) or a
FIFO named by mistake ends the command with one line instead of exhausting the memory or
waiting forever. The engine's own readers refuse the same files the same way."""

from __future__ import annotations

import io
import os
import stat

from rmi_learn.errors import InputError

#: Largest JSON (or TOML) file of options, trial config, grid or pipeline config read, in
#: bytes: real ones are a few kB, so the cap only stops a file that is not one.
MAX_JSON_BYTES = 16 * 1024 * 1024


def read_user_text(
    path: str | os.PathLike[str], what: str, label: str | None = None, limit: int = MAX_JSON_BYTES
) -> str:
    """The UTF-8 text of the regular file ``path`` (a symbolic link to one is followed),
    with line ends translated as :meth:`pathlib.Path.read_text` translates them.

    Raises :class:`~rmi_learn.errors.InputError` for anything but a regular file (a FIFO, a
    device, a directory) and for a file longer than ``limit`` bytes; ``what`` names the
    content ("grid file") and ``label`` the file (default: ``path``) in its message. A file
    that cannot be opened raises the OSError of the system, and one that is not UTF-8
    UnicodeDecodeError, as reading it with ``read_text`` would.
    """
    where = str(path) if label is None else label
    # Checked before opening: opening a FIFO waits for a writer, opening a device may act.
    _check_regular(os.stat(path).st_mode, where, what)
    # Non-blocking, so that a file replaced by a FIFO after the check cannot hang the open.
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    with os.fdopen(fd, "rb") as f:
        info = os.fstat(f.fileno())
        _check_regular(info.st_mode, where, what)
        if info.st_size > limit:
            raise InputError(_too_long(where, what, info.st_size, limit))
        # One byte past the cap shows a file that grew (or a size the system does not know).
        data = f.read(limit + 1)
    if len(data) > limit:
        raise InputError(_too_long(where, what, len(data), limit))
    return io.TextIOWrapper(io.BytesIO(data), encoding="utf-8").read()


def _check_regular(mode: int, where: str, what: str) -> None:
    if not stat.S_ISREG(mode):
        raise InputError(f"{where}: is not a regular file; a {what} must be one")


def _too_long(where: str, what: str, size: int, limit: int) -> str:
    cap = f"{limit >> 20} MiB" if limit % (1 << 20) == 0 else f"{limit} bytes"
    return f"{where}: {size} bytes or more exceed the limit of {cap} for a {what}"
