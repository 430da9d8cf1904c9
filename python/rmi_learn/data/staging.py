"""Output directories written whole or not at all: the files of a dataset build or export are
written into a temporary directory and moved into place at the end; on an error the
temporary directory goes, and so do the directories the command created.

A temporary directory is named ``.<name>.<pid>@<host>.<random>.tmp``; a process killed
before it could remove its own (``kill -9``) leaves it behind, and the next write into the
same directory removes it (:func:`remove_stale_temporaries`).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import socket
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import NoReturn

import polars as pl

from rmi_learn.data.runs import fsync_dir

#: Name of a temporary directory of this module: the name it stands for, the pid and host
#: of the process writing it, mkdtemp's random part.
_TEMPORARY = re.compile(r"^\..+\.(?P<pid>[0-9]+)@(?P<host>[A-Za-z0-9-]*)\.[a-z0-9_]+\.tmp$")


def _host() -> str:
    # Only the characters the name pattern allows, so a dotted host name cannot be misparsed.
    return re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname())


def temporary_dir(parent: Path, name: str) -> Path:
    """A new, empty temporary directory in ``parent`` for the output ``name``, named after
    this process so that :func:`remove_stale_temporaries` knows when it is abandoned."""
    return Path(
        tempfile.mkdtemp(prefix=f".{name}.{os.getpid()}@{_host()}.", suffix=".tmp", dir=parent)
    )


def remove_stale_temporaries(parent: Path) -> int:
    """Remove the temporary directories in ``parent`` (see :func:`temporary_dir`) whose
    process no longer runs; returns how many.

    The owner is told by the pid in the name rather than by a lock: the name exists from the
    moment the directory does, so a live writer's directory never looks abandoned (a lock
    taken just after creating the directory leaves such a moment), and nothing but the
    directory itself is left in ``parent``. A pid that a new process reuses only delays the
    removal; a directory of another host (a shared file system) is never removed, as its
    process cannot be checked from here.
    """
    if os.name != "posix":  # elsewhere os.kill(pid, 0) ends the process instead of testing it
        return 0
    host, removed = _host(), 0
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return 0
    for entry in entries:
        m = _TEMPORARY.match(entry.name)
        if m is None or m["host"] != host or not entry.is_dir(follow_symlinks=False):
            continue
        if not _running(int(m["pid"])):
            shutil.rmtree(entry.path, ignore_errors=True)
            removed += 1
    return removed


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True  # another user's process, or a pid the system cannot hold: left alone
    return True


def make_dirs(path: Path) -> list[Path]:
    """Create ``path`` and its missing ancestors; returns those this call created, deepest
    first, for :func:`remove_made_dirs`. An existing non-directory raises FileExistsError."""
    missing: list[Path] = []
    p = path
    while not p.is_dir() and p != p.parent:
        missing.append(p)
        p = p.parent
    made: list[Path] = []
    try:
        for d in reversed(missing):
            try:
                d.mkdir()
            except FileExistsError:
                if not d.is_dir():
                    raise
                continue  # made meanwhile by another process: not ours to remove
            made.append(d)
    except BaseException:
        remove_made_dirs(made[::-1])
        raise
    return made[::-1]


def remove_made_dirs(made: list[Path]) -> None:
    """Undo :func:`make_dirs`: remove the deepest directory it made with what it holds (this
    command's output), then the ancestors it made while they are empty."""
    for i, d in enumerate(made):
        if i == 0:
            shutil.rmtree(d, ignore_errors=True)
        else:
            try:
                d.rmdir()
            except OSError:
                return


def raise_named_for(exc: OSError, tmp: Path, dest: Path) -> NoReturn:
    """Raise ``exc``, a failure to write into the temporary directory ``tmp``, naming the
    path it stands for under ``dest`` instead (a write that failed names no file: ``dest``
    itself), so that the message names what the user asked for. An error without an OS
    error number is raised as it is."""
    where: Path | None = dest
    if isinstance(exc.filename, (str, bytes)):
        inside = Path(os.fsdecode(exc.filename))
        where = dest / inside.relative_to(tmp) if inside.is_relative_to(tmp) else None
    if exc.errno is None or where is None:
        raise exc
    raise OSError(exc.errno, exc.strerror, str(where)) from exc


@contextlib.contextmanager
def staged(parent: Path, name: str, dest: Path) -> Iterator[Path]:
    """A fresh temporary directory in ``parent`` (made with its missing folders) for the block
    to write ``dest`` in and move it into place. Stale temporaries of killed writers in
    ``parent`` go first; an OSError in the block is re-raised naming ``dest``; the temporary is
    always removed, and the folders made for it are removed when the block fails."""
    made = make_dirs(parent)
    try:
        remove_stale_temporaries(parent)
        tmp = temporary_dir(parent, name)
        try:
            yield tmp
        except OSError as exc:
            raise_named_for(exc, tmp, dest)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        remove_made_dirs(made)
        raise


def parquet_bytes(table: pl.DataFrame, metadata: Mapping[str, str] | None = None) -> bytes:
    """``table`` as Parquet bytes, with the key-value ``metadata`` in the file's footer if
    given. Encoded in memory so that a failing write (a full disk) raises its OSError from
    Python: polars reports one of its own writes as a ComputeError that loses the error
    number."""
    buf = io.BytesIO()
    if metadata is None:
        table.write_parquet(buf)
    else:
        table.write_parquet(buf, metadata=dict(metadata))
    return buf.getvalue()


def move_in(tmp: Path, dest: Path, names: list[str]) -> None:
    """Move the files ``names`` of the temporary directory ``tmp`` into the directory
    ``dest`` (on the same file system), in that order, replacing files of those names, then
    remove ``tmp``: a reader that checks the last name first never sees a mixture."""
    for name in names:
        os.replace(tmp / name, dest / name)
    fsync_dir(dest)
    tmp.rmdir()
