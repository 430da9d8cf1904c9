"""ParaView output: per-frame VTK XML PolyData (``.vtp``) files and a ``.pvd`` index.

Written by hand (no ``vtk`` package needed). Each frame has two pieces:

- ``particles_NNNNNN.vtp``: the fluid and skeleton particles as vertices, with point data
  ``phase`` (0 water, 1 sponge skeleton, 2 boundary when included), ``velocity`` (m/s),
  ``pressure`` (Pa), ``saturation`` (-, skeleton only; NaN for water), ``density`` (kg/m^3),
  ``porosity`` (-) and ``id`` (stable particle identity);
- ``bodies_NNNNNN.vtp``: the floor and the two pads as boxes (quads), with cell data
  ``body`` (index) and ``kinematic`` (0/1), and point data ``velocity`` (m/s).

The ``.pvd`` collection lists both pieces per time step (``part`` 0 and 1) with the
simulated time in s, and is rewritten after every frame, so a run cut short stays viewable.
Open it in ParaView (File > Open > ``trial.pvd``), then for the particles choose the
"Point Gaussian" representation (radius = particle radius) and colour by ``phase``,
``saturation`` or ``pressure``.

Data arrays are written ``ascii`` or ``binary`` (VTK's inline base64 with a UInt64 byte
count header, ``header_type="UInt64"``). Optional fluid surfaces: if the ``pysplashsurf``
package is importable, :func:`write_fluid_surface` reconstructs a triangle mesh of the water
with it; it is not a dependency of this project (and not installed in its test
environment), so that path is untested here.
"""

from __future__ import annotations

import base64
import os
import sys
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

#: Phase codes of the ``phase`` point array.
PHASE_CODES: dict[str, int] = {"fluid": 0, "solid": 1, "boundary": 2}

_VTK_TYPES: dict[str, str] = {
    "float64": "Float64",
    "float32": "Float32",
    "int64": "Int64",
    "int32": "Int32",
    "int8": "Int8",
    "uint8": "UInt8",
    "uint32": "UInt32",
    "uint64": "UInt64",
}

#: Byte order of the written binary data.
_BYTE_ORDER = "LittleEndian" if sys.byteorder == "little" else "BigEndian"


def _data_array(
    parent: ET.Element, name: str, values: npt.ArrayLike, *, binary: bool
) -> ET.Element:
    arr = np.ascontiguousarray(values)
    if arr.dtype == np.bool_:
        arr = arr.astype(np.uint8)
    vtk_type = _VTK_TYPES.get(arr.dtype.name)
    if vtk_type is None:
        raise TypeError(f"array {name!r} has dtype {arr.dtype}, which VTK output does not take")
    ncomp = 1 if arr.ndim == 1 else int(np.prod(arr.shape[1:]))
    el = ET.SubElement(parent, "DataArray", type=vtk_type, Name=name)
    if ncomp != 1:
        el.set("NumberOfComponents", str(ncomp))
    if binary:
        el.set("format", "binary")
        raw = arr.tobytes()
        header = np.array([len(raw)], dtype=np.uint64).tobytes()
        el.text = base64.b64encode(header + raw).decode("ascii")
    else:
        el.set("format", "ascii")
        flat = arr.reshape(-1)
        if arr.dtype.kind == "f":
            el.text = " ".join(repr(float(x)) for x in flat)
        else:
            el.text = " ".join(str(int(x)) for x in flat)
    return el


def polydata_xml(
    points: npt.ArrayLike,
    *,
    point_data: Mapping[str, npt.ArrayLike] | None = None,
    verts: bool = False,
    polys: Sequence[Sequence[int]] | None = None,
    cell_data: Mapping[str, npt.ArrayLike] | None = None,
    binary: bool = True,
) -> ET.ElementTree:
    """A VTK XML PolyData document.

    Parameters
    ----------
    points : (N, 3) array
        Point coordinates (m).
    point_data : dict, optional
        Name -> array of N values or (N, k) vectors.
    verts : bool
        Emit one vertex cell per point (what ParaView needs to show a point cloud).
    polys : list of index lists, optional
        Polygon cells (e.g. quads of boxes).
    cell_data : dict, optional
        Name -> one value per cell (vertex cells first, then polygons).
    binary : bool
        Base64 inline binary arrays (smaller, exact) instead of ascii.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = pts.shape[0]
    root = ET.Element(
        "VTKFile",
        type="PolyData",
        version="1.0",
        byte_order=_BYTE_ORDER,
        header_type="UInt64",
    )
    grid = ET.SubElement(root, "PolyData")
    polys = list(polys or [])
    nverts = n if verts else 0
    piece = ET.SubElement(
        grid,
        "Piece",
        NumberOfPoints=str(n),
        NumberOfVerts=str(nverts),
        NumberOfLines="0",
        NumberOfStrips="0",
        NumberOfPolys=str(len(polys)),
    )
    pd = ET.SubElement(piece, "PointData")
    for name, values in (point_data or {}).items():
        arr = np.asarray(values)
        if arr.shape[0] != n:
            raise ValueError(f"point array {name!r} has {arr.shape[0]} rows for {n} points")
        _data_array(pd, name, arr, binary=binary)
    cd = ET.SubElement(piece, "CellData")
    for name, values in (cell_data or {}).items():
        arr = np.asarray(values)
        if arr.shape[0] != nverts + len(polys):
            raise ValueError(f"cell array {name!r} has {arr.shape[0]} rows")
        _data_array(cd, name, arr, binary=binary)
    _data_array(ET.SubElement(piece, "Points"), "Points", pts, binary=binary)
    v = ET.SubElement(piece, "Verts")
    idx = np.arange(nverts, dtype=np.int64)
    _data_array(v, "connectivity", idx, binary=binary)
    _data_array(v, "offsets", idx + 1, binary=binary)
    p = ET.SubElement(piece, "Polys")
    conn = np.array([i for poly in polys for i in poly], dtype=np.int64)
    offs = np.cumsum([len(poly) for poly in polys], dtype=np.int64)
    _data_array(p, "connectivity", conn, binary=binary)
    _data_array(p, "offsets", offs, binary=binary)
    return ET.ElementTree(root)


def write_vtp(path: str | os.PathLike[str], tree: ET.ElementTree) -> Path:
    """Write a PolyData document to ``path`` atomically (temporary name, then rename)."""
    from rmi_learn.data.runs import atomic_write_bytes

    root = tree.getroot()
    assert root is not None
    data = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return atomic_write_bytes(path, lambda f: f.write(data))


def read_vtp_arrays(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read back a ``.vtp`` written by this module (ascii or binary): ``{"points": (N, 3),
    "n_points", "n_verts", "n_polys", "point_data": {name: array}, "cell_data": {...}}``.
    Meant for tests and quick checks, not a general VTK reader."""
    root = ET.parse(path).getroot()
    piece = root.find("PolyData/Piece")
    if piece is None:
        raise ValueError(f"{path}: not a PolyData file")

    def decode(el: ET.Element) -> np.ndarray:
        dtype = {v: k for k, v in _VTK_TYPES.items()}[el.get("type", "")]
        ncomp = int(el.get("NumberOfComponents", "1"))
        text = (el.text or "").strip()
        if el.get("format") == "binary":
            raw = base64.b64decode(text)
            nbytes = int(np.frombuffer(raw[:8], dtype=np.uint64)[0])
            arr = np.frombuffer(raw[8 : 8 + nbytes], dtype=dtype)
        else:
            arr = np.array(text.split(), dtype=dtype) if text else np.zeros(0, dtype=dtype)
        return arr.reshape(-1, ncomp) if ncomp > 1 else arr

    def arrays(tag: str) -> dict[str, np.ndarray]:
        sec = piece.find(tag)
        return {} if sec is None else {el.get("Name", ""): decode(el) for el in sec}

    points_el = piece.find("Points/DataArray")
    assert points_el is not None
    return {
        "n_points": int(piece.get("NumberOfPoints", "0")),
        "n_verts": int(piece.get("NumberOfVerts", "0")),
        "n_polys": int(piece.get("NumberOfPolys", "0")),
        "points": decode(points_el),
        "point_data": arrays("PointData"),
        "cell_data": arrays("CellData"),
    }


# --------------------------------------------------------------------------------------
# Frames of a simulation


def particles_tree(
    sim: Any, *, include_boundary: bool = False, binary: bool = True
) -> ET.ElementTree:
    """The particles of an ``rmi_sph.Trial`` as vertices with point data (see module
    docstring). ``include_boundary`` adds the floor and pad particles (phase 2)."""
    kinds = ["fluid", "solid"] + (["boundary"] if include_boundary else [])
    pos, vel, phase, pres, sat, dens, por, ids = [], [], [], [], [], [], [], []
    for kind in kinds:
        d = sim.particles(kind)
        n = d["positions"].shape[0]
        nan = np.full(n, np.nan)
        pos.append(d["positions"])
        vel.append(d["velocities"])
        phase.append(np.full(n, PHASE_CODES[kind], dtype=np.int32))
        pres.append(d.get("pressure", np.zeros(n)))
        sat.append(d.get("saturation", nan))
        dens.append(d.get("density", nan))
        por.append(d.get("porosity", nan))
        ids.append(d["id"].astype(np.int64) if "id" in d else np.full(n, -1, dtype=np.int64))
    points = np.concatenate(pos) if pos else np.zeros((0, 3))
    return polydata_xml(
        points,
        point_data={
            "phase": np.concatenate(phase),
            "velocity": np.concatenate(vel),
            "pressure": np.concatenate(pres),
            "saturation": np.concatenate(sat),
            "density": np.concatenate(dens),
            "porosity": np.concatenate(por),
            "id": np.concatenate(ids),
        },
        verts=True,
        binary=binary,
    )


#: Faces of a box over its corners numbered by bits (x, y, z), outward winding.
_BOX_FACES = (
    (0, 2, 6, 4),  # -x
    (1, 5, 7, 3),  # +x
    (0, 4, 5, 1),  # -y
    (2, 3, 7, 6),  # +y
    (0, 1, 3, 2),  # -z
    (4, 6, 7, 5),  # +z
)


def _rotation_matrix(q: Sequence[float]) -> np.ndarray:
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def bodies_tree(bodies: Sequence[Mapping[str, Any]], *, binary: bool = True) -> ET.ElementTree:
    """Boxes of the rigid bodies (``Trial.bodies()``): 8 corners and 6 quads each."""
    corners = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], dtype=np.float64)
    corners = 2.0 * corners - 1.0
    points, vel, polys, body, kinematic = [], [], [], [], []
    for bi, b in enumerate(bodies):
        he = np.asarray(b["half_extents"], dtype=np.float64)
        rot = _rotation_matrix(b["rotation"])
        base = 8 * bi
        points.append((corners * he) @ rot.T + np.asarray(b["position"]))
        vel.append(np.tile(np.asarray(b["velocity"], dtype=np.float64), (8, 1)))
        polys.extend([tuple(base + i for i in face) for face in _BOX_FACES])
        body.extend([bi] * 6)
        kinematic.extend([int(bool(b["kinematic"]))] * 6)
    return polydata_xml(
        np.concatenate(points) if points else np.zeros((0, 3)),
        point_data={"velocity": np.concatenate(vel) if vel else np.zeros((0, 3))},
        polys=polys,
        cell_data={
            "body": np.array(body, dtype=np.int32),
            "kinematic": np.array(kinematic, dtype=np.uint8),
        },
        binary=binary,
    )


class FrameWriter:
    """Writes frames of a simulation into ``directory`` and keeps ``<name>.pvd`` current.

    Parameters
    ----------
    directory : path
        Output folder (created). Frames go to ``directory/frames/``.
    name : str
        Stem of the collection file (``trial`` -> ``trial.pvd``).
    binary : bool
        Inline base64 arrays (default) or ascii.
    include_boundary : bool
        Also write the floor and pad particles into the particle files.
    surface : bool
        Also reconstruct the water surface with ``pysplashsurf`` (if importable) per frame.
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        *,
        name: str = "trial",
        binary: bool = True,
        include_boundary: bool = False,
        surface: bool = False,
    ) -> None:
        self.directory = Path(directory)
        self.frames_dir = self.directory / "frames"
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        self.pvd_path = self.directory / f"{name}.pvd"
        self.binary = binary
        self.include_boundary = include_boundary
        self.surface = surface and surface_available()
        self.entries: list[tuple[float, int, str]] = []
        self.count = 0

    def write(self, sim: Any) -> list[Path]:
        """Write the current state of ``sim`` as the next frame; returns the files."""
        k = self.count
        t = float(sim.time)
        files = [
            (
                0,
                f"particles_{k:06d}.vtp",
                particles_tree(sim, include_boundary=self.include_boundary, binary=self.binary),
            ),
            (1, f"bodies_{k:06d}.vtp", bodies_tree(sim.bodies(), binary=self.binary)),
        ]
        out: list[Path] = []
        for part, fname, tree in files:
            out.append(write_vtp(self.frames_dir / fname, tree))
            self.entries.append((t, part, f"frames/{fname}"))
        if self.surface:
            fname = f"surface_{k:06d}.vtp"
            if write_fluid_surface(sim, self.frames_dir / fname, binary=self.binary):
                out.append(self.frames_dir / fname)
                self.entries.append((t, 2, f"frames/{fname}"))
        self.count += 1
        self.write_pvd()
        return out

    def write_pvd(self) -> Path:
        """(Re)write the ``.pvd`` collection of every frame written so far."""
        from rmi_learn.data.runs import atomic_write_bytes

        root = ET.Element("VTKFile", type="Collection", version="0.1", byte_order=_BYTE_ORDER)
        coll = ET.SubElement(root, "Collection")
        for t, part, fname in self.entries:
            ET.SubElement(coll, "DataSet", timestep=repr(t), group="", part=str(part), file=fname)
        data = ET.tostring(root, encoding="utf-8", xml_declaration=True)
        return atomic_write_bytes(self.pvd_path, lambda f: f.write(data))


# --------------------------------------------------------------------------------------
# Optional surface reconstruction


def surface_available() -> bool:
    """Whether the optional ``pysplashsurf`` package can be imported."""
    try:
        import pysplashsurf  # type: ignore[import-not-found]  # noqa: F401
    except ImportError:
        return False
    return True


def write_fluid_surface(
    sim: Any,
    path: str | os.PathLike[str],
    *,
    smoothing_length: float = 2.0,
    cube_size: float = 0.5,
    iso_surface_threshold: float = 0.6,
    binary: bool = True,
) -> bool:
    """Reconstruct the water surface with ``pysplashsurf`` and write it as a triangle
    ``.vtp``. Lengths are in multiples of the particle radius (splashsurf's convention).

    Returns False (and writes nothing) when ``pysplashsurf`` is not installed or there is
    no water. Untested in this repository's CI (the package is optional and not installed).
    """
    try:
        import pysplashsurf
    except ImportError:
        return False
    fluid = np.asarray(sim.particles("fluid")["positions"], dtype=np.float64)
    if fluid.shape[0] == 0:
        return False
    radius = float(sim.config["particle_radius"])
    result = pysplashsurf.reconstruction_pipeline(
        fluid,
        particle_radius=radius,
        rest_density=1000.0,
        smoothing_length=smoothing_length,
        cube_size=cube_size,
        iso_surface_threshold=iso_surface_threshold,
    )
    mesh: Any = result[0] if isinstance(result, tuple) else result
    mesh = getattr(mesh, "mesh", mesh)
    verts = mesh.vertices if hasattr(mesh, "vertices") else mesh.get_vertices()
    tris = mesh.triangles if hasattr(mesh, "triangles") else mesh.get_triangles()
    tree = polydata_xml(
        np.asarray(verts, dtype=np.float64),
        polys=np.asarray(tris, dtype=np.int64).tolist(),
        binary=binary,
    )
    write_vtp(path, tree)
    return True
