"""The export: read the dataset, build its episodes, write one layout into a staged
directory and move it into place."""

from __future__ import annotations

import os
from pathlib import Path

from rmi_learn.data import staging
from rmi_learn.data.export_lerobot import layout_v21, layout_v30
from rmi_learn.data.export_lerobot.episodes import build_episodes, read_source
from rmi_learn.errors import InputError

#: The layouts written, newest (the default) first.
CODEBASE_VERSIONS: tuple[str, ...] = (layout_v30.VERSION, layout_v21.VERSION)
_WRITERS = {layout_v30.VERSION: layout_v30.write, layout_v21.VERSION: layout_v21.write}


def _check_out(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise InputError(f"--out {out} exists and is not an empty directory; choose a new one")


def export_lerobot(
    data_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    codebase_version: str = layout_v30.VERSION,
) -> Path:
    """Export the dataset built in ``data_dir`` (``rmi dataset build``) to LeRobot's layout
    of ``codebase_version`` (one of :data:`CODEBASE_VERSIONS`) in ``out_dir`` and return
    ``out_dir`` (see the package docstring for the columns). ``out_dir`` must not exist or be
    an empty directory; a symbolic link to an empty directory is kept, and the export written
    where it points.

    Raises :class:`~rmi_learn.errors.InputError` for an unknown ``codebase_version`` (or
    v3.0 without pyarrow installed), an
    ``out_dir`` that holds anything, a damaged dataset, one without the named action channels
    or with a phase that is not one of ``schema.PHASES``; FileNotFoundError when ``data_dir``
    is not a built dataset; an OSError naming ``out_dir`` (or the file in it) when the export
    cannot be written.
    """
    if codebase_version not in _WRITERS:
        raise InputError(
            f"--codebase-version must be one of {', '.join(CODEBASE_VERSIONS)}, "
            f"got {codebase_version!r}"
        )
    if codebase_version == layout_v30.VERSION:
        layout_v30.require_pyarrow()
    data, out = Path(data_dir), Path(out_dir)
    _check_out(out)
    source = read_source(data)
    # Through a link to a directory the export goes where the link points; the link stays.
    target = Path(os.path.realpath(out))
    with staging.staged(target.parent, target.name, out) as tmp:
        _WRITERS[codebase_version](tmp, source, build_episodes(source))
        _check_out(out)  # again: another writer may have filled it meanwhile
        if target.exists():
            target.rmdir()
        os.rename(tmp, target)
    return out
