"""The sweep's hold on its output directory: the name of its lock (:data:`LOCK_FILE`, see
:mod:`rmi_learn.data.output_lock`), and the temporaries a killed sweep left behind removed
before it resumes (:func:`clean_temporaries`)."""

from __future__ import annotations

from pathlib import Path

from rmi_learn.data.output_lock import lock_file
from rmi_learn.data.runs import TMP_SUFFIX
from rmi_learn.data.sweep.index import RUNS_SUBDIR

#: The command name the sweep locks its output directory under.
LOCK_NAME = "sweep"
LOCK_FILE = lock_file(LOCK_NAME)


def clean_temporaries(out: Path) -> int:
    """Remove temporaries left by a killed sweep (``.<name>.<random>.tmp``); returns how many."""
    n = 0
    for tmp in list(out.glob(f".*{TMP_SUFFIX}")) + list(
        (out / RUNS_SUBDIR).rglob(f".*{TMP_SUFFIX}")
    ):
        tmp.unlink(missing_ok=True)
        n += 1
    return n
