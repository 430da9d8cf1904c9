"""Where in the sponge does the released water start?

Runs one scripted grasp-lift-squeeze trial through ``rmi_sph.Trial`` and sorts the pore
water by its initial depth below the sponge's surface (the skeleton's rest box, grown by one
particle radius to the block's faces). For each depth band it prints the water that started
there and the part of it that is no longer retained when the trial ends. At a converged
resolution the release would not depend on how many particle layers the surface band holds;
``studies/resolution.py`` shows that the amount does, and this shows from where it comes.

    .venv/bin/python studies/drain_depth.py --radius 0.008 [--size 8] [--porosity 0.7] \\
        [--hold 140] [--squeeze 150] [--seed 0] [--threads 2] [--json]

Phases and time step are those of ``studies/grids/resolution/`` (the study's phases at the
engine's default dt = 1 ms), read from its grid file by ``studies/series_trial.py``.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

# The study scripts are files, not a package: make their shared module importable however the
# script is loaded (run from anywhere, or loaded by path in the tests).
sys.path.insert(0, str(Path(__file__).resolve().parent))
from series_trial import add_condition_args, report, trial_config  # noqa: E402

#: Depth bands (m) below the sponge's surface (the last one reaches past any sponge's centre).
BANDS_M: tuple[tuple[float, float], ...] = ((0.0, 0.01), (0.01, 0.02), (0.02, 1.0))


def depths(x0: np.ndarray, rest_positions: np.ndarray, radius: float) -> np.ndarray:
    """Depth (m) of each point of ``x0`` (N, 3) below the nearest face of the skeleton's
    rest box grown by ``radius`` (the block's faces); negative outside it."""
    lo = rest_positions.min(axis=0) - radius
    hi = rest_positions.max(axis=0) + radius
    depth: np.ndarray = np.minimum((x0 - lo).min(axis=1), (hi - x0).min(axis=1))
    return depth


def release_by_depth(
    depth: np.ndarray,
    mass: np.ndarray,
    retained: np.ndarray,
    bands: Sequence[tuple[float, float]] = BANDS_M,
) -> list[dict[str, float]]:
    """Per band ``[lo, hi)``: ``water_g`` that started there and ``released_g`` of it that is
    not retained at the end (particles that started outside the block are left out)."""
    out = []
    for lo, hi in bands:
        band = (depth >= lo) & (depth < hi)
        out.append(
            {
                "lo_m": lo,
                "hi_m": hi,
                "water_g": 1000.0 * float(mass[band].sum()),
                "released_g": 1000.0 * float(mass[band & ~retained].sum()),
            }
        )
    return out


def run(a: argparse.Namespace) -> dict[str, Any]:
    """The trial of ``a``'s options; the initial depth of every fluid particle, matched by id
    with its retained flag at the end."""
    import rmi_sph

    cfg = trial_config(a)
    sim = rmi_sph.Trial(cfg, num_threads=a.threads)
    rest = np.asarray(sim.particles("solid")["rest_positions"])
    f0 = sim.particles("fluid")
    order0 = np.argsort(np.asarray(f0["id"]))
    depth = depths(np.asarray(f0["positions"]), rest, a.radius)[order0]
    mass = np.asarray(f0["mass"])[order0]
    t0 = time.perf_counter()
    while sim.observation()["phase"] != "done":
        sim.step(200)
    f1 = sim.particles("fluid")
    retained = np.asarray(f1["retained"]).astype(bool)[np.argsort(np.asarray(f1["id"]))]
    return {
        "radius_m": a.radius,
        "size_cm": a.size,
        "wall_s": time.perf_counter() - t0,
        "bands": release_by_depth(depth, mass, retained),
    }


def show(a: argparse.Namespace, res: dict[str, Any]) -> None:
    """The result as text: the totals, then each depth band."""
    total = sum(b["water_g"] for b in res["bands"])
    gone = sum(b["released_g"] for b in res["bands"])
    print(
        f"{a.size} cm, r = {1000 * a.radius:g} mm: {total:.0f} g of pore water, "
        f"{gone:.1f} g released ({res['wall_s']:.0f} s)"
    )
    for b in res["bands"]:
        share = 100 * b["released_g"] / b["water_g"] if b["water_g"] else 0.0
        band = f"{1000 * b['lo_m']:.0f}-{1000 * b['hi_m']:.0f} mm"
        if b["hi_m"] >= 1.0:
            band = f">= {1000 * b['lo_m']:.0f} mm"
        print(
            f"  depth {band:9s}: water {b['water_g']:6.1f} g, "
            f"released {b['released_g']:6.1f} g ({share:.0f} %)"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_condition_args(ap)
    return report("drain_depth", run, ap.parse_args(argv), show)


if __name__ == "__main__":
    raise SystemExit(main())
