"""The report's figure files: drawn with a headless pyplot or copied from a stage's output into
the report's ``figures/`` folder, every file written atomically."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

from rmi_learn.data.runs import atomic_write_bytes

FIG_SUBDIR = "figures"


def headless_pyplot() -> Any:
    """pyplot on the Agg backend (no display needed); the backend is chosen before pyplot
    is first imported."""
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_fig(fig: Any, path: Path) -> None:
    """Write ``fig`` as a PNG at ``path``."""
    # savefig into a temporary name and rename, so a killed report leaves no broken PNG.
    atomic_write_bytes(path, lambda f: fig.savefig(f, format="png", dpi=120))


def copy_fig(src: Path, dst_dir: Path) -> str | None:
    """Copy the figure ``src`` into ``dst_dir``; its path relative to the report, or
    ``None`` when the stage did not draw it."""
    if not src.exists():
        return None
    dst_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(dst_dir / src.name, lambda f: f.write(src.read_bytes()))
    return f"{FIG_SUBDIR}/{src.name}"
