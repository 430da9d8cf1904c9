"""The sweep's hold on its output directory: an exclusive lock for the sweep's duration
(:func:`sweep_lock`), and the temporaries a killed sweep left behind removed before it
resumes (:func:`clean_temporaries`)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from rmi_learn.data.runs import TMP_SUFFIX
from rmi_learn.data.sweep.index import RUNS_SUBDIR

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: no lock
    fcntl = None  # type: ignore[assignment]

LOCK_FILE = ".sweep.lock"


def clean_temporaries(out: Path) -> int:
    """Remove temporaries left by a killed sweep (``.<name>.<random>.tmp``); returns how many."""
    n = 0
    for tmp in list(out.glob(f".*{TMP_SUFFIX}")) + list(
        (out / RUNS_SUBDIR).rglob(f".*{TMP_SUFFIX}")
    ):
        tmp.unlink(missing_ok=True)
        n += 1
    return n


@contextlib.contextmanager
def sweep_lock(out: Path) -> Iterator[None]:
    """Exclusive lock on ``OUT/.sweep.lock`` for the sweep's duration: two sweeps never write
    one directory at once. The kernel drops the lock when its holder dies, even by kill -9."""
    f = open(out / LOCK_FILE, "a+b")  # noqa: SIM115 - held for the whole sweep
    try:
        if fcntl is not None:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError as exc:
                raise RuntimeError(
                    f"another sweep is writing {out} (lock {out / LOCK_FILE})"
                ) from exc
        yield
    finally:
        f.close()
