"""Side view of a trial's particles as an RGB image, drawn with numpy alone.

The view projects onto the x-z plane (x across the gripper, z up): the floor and the pads
(boundary particles) in grey, the sponge skeleton shaded from dry tan to wet brown by its
saturation, and the water in blue. Water is drawn first and the skeleton over it, so blue
shows the water outside the skeleton (dripping, pooled on the floor) and the sponge's shade
shows how wet it still is. Each particle is a filled disc of its radius in pixels (a single
pixel where that rounds to 0). The window is fixed per episode (:func:`view_of`), so the
frames of an episode line up as a video. Used by ``SpongeSqueezeEnv(render_mode="rgb_array")``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

import rmi_sph

Image = npt.NDArray[np.uint8]

BACKGROUND = np.array([246, 246, 246], dtype=np.uint8)
FLOOR = np.array([160, 160, 160], dtype=np.uint8)
PAD = np.array([70, 80, 100], dtype=np.uint8)
WATER = np.array([40, 110, 220], dtype=np.uint8)
#: Skeleton colour at saturation 0 and 1.
DRY = np.array([228, 204, 150], dtype=np.float64)
WET = np.array([125, 95, 60], dtype=np.float64)

#: Free space around the sponge and pads, as a fraction of the larger extent of the scene.
MARGIN = 0.08


@dataclass(frozen=True)
class View:
    """A window of the x-z plane mapped onto an image: pixel column ``(x - x0) * scale``,
    row ``height - 1 - (z - z0) * scale`` (``x0``, ``z0`` in m, ``scale`` in px/m)."""

    x0: float
    z0: float
    scale: float
    height: int
    width: int
    #: Disc radius of a particle (px).
    radius_px: int


def view_of(trial: rmi_sph.Trial, shape: tuple[int, int]) -> View:
    """The window (``shape`` = (height, width) px) around the sponge and the pads of
    ``trial`` as they are now, with room above them for the lift (``lift_height``, m).
    The scale is the same along x and z; the scene is centred in the image."""
    height, width = int(shape[0]), int(shape[1])
    if height < 8 or width < 8:
        raise ValueError(f"render shape must be at least 8 x 8 pixels, got {shape!r}")
    solid = trial.particles("solid")["positions"]
    boundary = trial.particles("boundary")
    pads = boundary["positions"][np.isin(boundary["body"], _pad_bodies(trial))]
    pts = np.concatenate([solid, pads]) if len(pads) else solid
    cfg = trial.config
    lo = pts.min(axis=0)
    hi = pts.max(axis=0)
    hi[2] += float(cfg["controller"]["lift_height"])
    pad = MARGIN * float(max(hi[0] - lo[0], hi[2] - lo[2]))
    lo, hi = lo - pad, hi + pad
    scale = min((width - 1) / (hi[0] - lo[0]), (height - 1) / (hi[2] - lo[2]))
    # Centre the scene in whichever direction has room to spare.
    x0 = 0.5 * (lo[0] + hi[0]) - 0.5 * (width - 1) / scale
    z0 = 0.5 * (lo[2] + hi[2]) - 0.5 * (height - 1) / scale
    radius_px = int(round(float(cfg["particle_radius"]) * scale))
    return View(float(x0), float(z0), float(scale), height, width, radius_px)


def _pad_bodies(trial: rmi_sph.Trial) -> list[int]:
    return [i for i, b in enumerate(trial.bodies()) if str(b["name"]).startswith("pad")]


def _disc(radius: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    d = np.arange(-radius, radius + 1)
    dx, dz = np.meshgrid(d, d)
    inside = dx * dx + dz * dz <= radius * radius
    return dx[inside], dz[inside]


def _splat(
    canvas: Image,
    view: View,
    positions: npt.NDArray[np.float64],
    colour: npt.NDArray[np.uint8],
) -> None:
    """Draw discs at ``positions`` (N, 3) m in ``colour`` (RGB, or one per particle) on
    ``canvas``, the image with a border of twice ``view.radius_px`` on every side (so the
    disc of a particle at most one radius outside the image needs no clipping)."""
    r = view.radius_px
    col = np.floor((positions[:, 0] - view.x0) * view.scale + 0.5).astype(np.int64)
    row = (
        view.height - 1 - np.floor((positions[:, 2] - view.z0) * view.scale + 0.5).astype(np.int64)
    )
    inside = (col >= -r) & (col < view.width + r) & (row >= -r) & (row < view.height + r)
    stride = view.width + 4 * r
    centre = (row[inside] + 2 * r) * stride + col[inside] + 2 * r
    c = colour if colour.ndim == 1 else colour[inside]
    flat = canvas.reshape(-1, 3)
    for dx, dz in zip(*_disc(r), strict=True):
        flat[centre + dz * stride + dx] = c


def side_view(trial: rmi_sph.Trial, view: View) -> Image:
    """The particles of ``trial`` seen from the side through ``view``: an (H, W, 3) uint8
    RGB image (see the module docstring for what is drawn how)."""
    b = 2 * view.radius_px  # the border _splat draws into
    img = np.empty((view.height + 2 * b, view.width + 2 * b, 3), dtype=np.uint8)
    img[:] = BACKGROUND
    boundary = trial.particles("boundary")
    is_pad = np.isin(boundary["body"], _pad_bodies(trial))
    _splat(img, view, boundary["positions"][~is_pad], FLOOR)
    _splat(img, view, trial.particles("fluid")["positions"], WATER)
    solid = trial.particles("solid")
    s = np.clip(np.nan_to_num(solid["saturation"], nan=0.0), 0.0, 1.0)[:, None]
    shade = np.rint(DRY + (WET - DRY) * s).astype(np.uint8)
    _splat(img, view, solid["positions"], shade)
    _splat(img, view, boundary["positions"][is_pad], PAD)
    return np.ascontiguousarray(img[b : b + view.height, b : b + view.width])
