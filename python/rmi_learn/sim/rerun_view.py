"""An interactive 3D view of trials without ParaView: one rerun recording (``rmi view``).

:func:`write_recording` reads run directories written by ``rmi simulate`` and writes a
``.rrd`` file for the rerun viewer (``pip install rerun-sdk``, then ``rerun OUT.rrd``). On
one timeline ``time`` (simulated seconds) it holds, per run under ``runs/<name>/``:

- ``particles/water``, ``particles/skeleton`` (and ``particles/boundary`` when the frames
  have them): the particles of every VTK frame (``rmi simulate --vtk-every N``) as points
  of the particle radius;
- ``bodies``: the floor and the two gripper pads as box meshes (pads red, floor grey);
- ``force/F_meas``, ``force/F_target`` (N), ``water/retained_g``, ``water/expelled_g`` (g),
  ``gripper/width_mm`` and ``gripper/lift_mm`` (mm): the run file's series at every record;
- ``phase``: a text entry at each controller phase change.

A run without frames contributes its series only. rerun-sdk is an optional dependency,
imported when a recording is written; without it :func:`write_recording` raises
:class:`~rmi_learn.errors.StageFailure` saying how to install it.
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.data.runs import read_run
from rmi_learn.errors import InputError, StageFailure
from rmi_learn.sim.vtk import read_vtp_arrays

#: How to install the optional viewer library.
RERUN_INSTALL = "pip install rerun-sdk"

#: RGB of the particle kinds, by the ``phase`` code of the VTK frames.
KIND_COLORS: dict[int, tuple[str, tuple[int, int, int]]] = {
    0: ("water", (40, 120, 230)),
    1: ("skeleton", (225, 190, 90)),
    2: ("boundary", (150, 150, 150)),
}
#: RGB of the kinematic bodies (the pads) and of the others (the floor).
PAD_COLOR, FLOOR_COLOR = (210, 60, 50), (170, 170, 170)

#: Run-file channel -> (entity below the run, scale to the shown unit).
SERIES: dict[str, tuple[str, float]] = {
    "F_meas": ("force/F_meas", 1.0),
    "F_target": ("force/F_target", 1.0),
    "M_L": ("water/retained_g", 1e3),
    "M_expelled": ("water/expelled_g", 1e3),
    "w": ("gripper/width_mm", 1e3),
    "lift_height": ("gripper/lift_mm", 1e3),
}

#: Faces of a box over its corners numbered by bits (x, y, z), as the VTK body frames
#: write them (:mod:`rmi_learn.sim.vtk`), split into two triangles each.
_BOX_TRIANGLES = np.array(
    [
        tri
        for a, b, c, d in (
            (0, 2, 6, 4),
            (1, 5, 7, 3),
            (0, 4, 5, 1),
            (2, 3, 7, 6),
            (0, 1, 3, 2),
            (4, 6, 7, 5),
        )  # fmt: skip
        for tri in ((a, b, c), (a, c, d))
    ],
    dtype=np.uint32,
)


def rerun_available() -> bool:
    """Whether the optional ``rerun`` package (rerun-sdk) can be imported."""
    return importlib.util.find_spec("rerun") is not None


def _import_rerun() -> Any:
    try:
        import rerun  # type: ignore[import-not-found,unused-ignore]
    except ImportError:
        raise StageFailure(f"needs rerun-sdk, which is not installed: {RERUN_INSTALL}") from None
    return rerun


def run_file_of(path: str | os.PathLike[str]) -> Path:
    """The run file of ``path``: ``path/run.parquet`` for a run directory, else ``path``.
    Raises :class:`~rmi_learn.errors.InputError` when there is none."""
    p = Path(path)
    file = p / "run.parquet" if p.is_dir() else p
    if not file.is_file():
        raise InputError(f"{path}: no run file (give `rmi simulate --out` directories)")
    return file


def frames_of(run_dir: Path) -> list[tuple[float, int, Path]]:
    """``(time s, part, file)`` of the VTK frames listed in ``run_dir/trial.pvd`` (part 0:
    particles, 1: bodies), or none when the run was simulated without frames."""
    pvd = run_dir / "trial.pvd"
    if not pvd.is_file():
        return []
    try:
        root = ET.parse(pvd).getroot()
    except ET.ParseError as exc:
        raise InputError(f"{pvd}: not a frame index ({exc})") from exc
    return [
        (float(d.get("timestep", "nan")), int(d.get("part", "0")), run_dir / d.get("file", ""))
        for d in root.iter("DataSet")
    ]


def _labels(files: Sequence[Path]) -> list[str]:
    """One entity name per run: its directory's name, made unique, in rerun's path syntax."""
    out: list[str] = []
    for i, f in enumerate(files):
        name = re.sub(r"[^A-Za-z0-9_-]+", "_", f.parent.name).strip("_") or "run"
        out.append(name if name not in out else f"{name}_{i}")
    return out


@contextlib.contextmanager
def staged_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """A temporary file beside ``path`` to write ``path``'s contents into: the folders
    leading to ``path`` are made first, and when the block completes the temporary replaces
    ``path``. When the block fails, the temporary and the folders made here are removed
    again (a file already at ``path`` stays as it was), so no partial file is left."""
    out = Path(path)
    made = [p for p in (out.parent, *out.parent.parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    try:
        yield tmp
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        for folder in made:  # innermost first
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise


def write_recording(
    runs: Sequence[str | os.PathLike[str]],
    rrd: str | os.PathLike[str],
    *,
    every: int = 1,
) -> dict[str, Any]:
    """Write the runs ``runs`` (``rmi simulate`` output directories, or run files) into the
    rerun recording ``rrd`` (see the module docstring); every ``every``-th VTK frame is
    included. Missing folders of ``rrd`` are made; the file is written under a temporary
    name and renamed when complete (:func:`staged_output`).
    Returns ``{"path", "runs", "frames", "records"}`` (frames and records summed over runs).

    Raises :class:`~rmi_learn.errors.InputError` for a path without a run file, and
    :class:`~rmi_learn.errors.StageFailure` without rerun-sdk (both before anything is
    written)."""
    if every < 1:
        raise InputError(f"every must be >= 1, got {every}")
    files = [run_file_of(r) for r in runs]
    if not files:
        raise InputError("give at least one run directory")
    rr = _import_rerun()
    out = Path(rrd)
    frames_total = records_total = 0
    with staged_output(out) as tmp:
        rec = rr.RecordingStream("rmi_view")
        rec.save(tmp)
        try:
            rec.log("runs", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
            for file, label in zip(files, _labels(files), strict=True):
                frames, records = _log_run(rr, rec, file, f"runs/{label}", every)
                frames_total += frames
                records_total += records
            rec.flush()
        finally:
            # Closing the file sink completes the file (or releases it after an error).
            rec.disconnect()
    return {"path": out, "runs": len(files), "frames": frames_total, "records": records_total}


def _log_run(rr: Any, rec: Any, file: Path, root: str, every: int) -> tuple[int, int]:
    """One run's series, phase changes and frames under ``root``; returns the particle
    frames and the records logged."""
    df, meta = read_run(file)
    radius = float(meta.get("config", {}).get("particle_radius", 0.005))
    t = df["time"].to_numpy()
    index = [rr.TimeColumn("time", duration=t)]
    for channel, (entity, scale) in SERIES.items():
        if channel in df.columns:
            values = df[channel].cast(float).to_numpy() * scale
            rec.send_columns(
                f"{root}/{entity}", indexes=index, columns=rr.Scalars.columns(scalars=values)
            )
    phases = df["phase"].to_list()
    for k, phase in enumerate(phases):
        if k == 0 or phase != phases[k - 1]:
            rec.set_time("time", duration=float(t[k]))
            rec.log(f"{root}/phase", rr.TextLog(f"phase {phase}"))
    parts: dict[int, list[tuple[float, Path]]] = {0: [], 1: []}
    for time_s, part, path in frames_of(file.parent):
        if part in parts:
            parts[part].append((time_s, path))
    frames_total = 0
    for part, frames in parts.items():
        for time_s, path in frames[::every]:
            rec.set_time("time", duration=time_s)
            data = read_vtp_arrays(path)
            if part == 0:
                _log_particles(rr, rec, f"{root}/particles", data, radius)
                frames_total += 1
            else:
                _log_bodies(rr, rec, f"{root}/bodies", data)
    return frames_total, df.height


def _log_particles(rr: Any, rec: Any, base: str, data: dict[str, Any], radius: float) -> None:
    """One frame's particles, one entity per kind."""
    codes = np.asarray(data["point_data"].get("phase", np.zeros(data["n_points"])), dtype=int)
    points = np.asarray(data["points"], dtype=np.float64).reshape(-1, 3)
    for code, (kind, color) in KIND_COLORS.items():
        mask = codes == code
        if mask.any():
            rec.log(f"{base}/{kind}", rr.Points3D(points[mask], radii=radius, colors=color))


def _log_bodies(rr: Any, rec: Any, base: str, data: dict[str, Any]) -> None:
    """One frame's bodies as one mesh of boxes (8 corners each)."""
    points = np.asarray(data["points"], dtype=np.float64).reshape(-1, 3)
    n = points.shape[0] // 8
    if n == 0:
        return
    kinematic = np.asarray(data["cell_data"].get("kinematic", np.zeros(6 * n)))[::6]
    colors = np.repeat([PAD_COLOR if k else FLOOR_COLOR for k in kinematic], 8, axis=0)
    triangles = np.concatenate([_BOX_TRIANGLES + 8 * i for i in range(n)])
    rec.log(
        base,
        rr.Mesh3D(vertex_positions=points, triangle_indices=triangles, vertex_colors=colors),
    )
