"""Is the water a sponge releases converged in the particle size?

Give sweeps of the same conditions at different particle radii (``studies/grids/resolution/``:
the 8 and 10 cm sponges at porosity 0.7, holding 140 N, squeeze 150 N, r = 8 / 6.5 / 5 / 4 mm,
all at dt = 1 ms). Per condition it prints, for each radius, the initial pore water and the
water removed in each controller phase and in all (g, and % of the initial water). A converged
engine gives the same grams at every radius, up to one particle's mass.

    for r in 8 6.5 5 4; do .venv/bin/rmi sweep --grid studies/grids/resolution/r${r}mm.json \\
        --out results/resolution/r$r --workers 2 --threads-per-run 1; done
    .venv/bin/python studies/resolution.py results/resolution/* [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

#: Controller phases whose removal is reported, in order.
PHASES = ("ramp", "hold", "lift", "waiting", "squeeze")


def load(sweeps: list[str | Path]) -> dict[tuple[Any, ...], list[dict[str, Any]]]:
    """``{(size cm, porosity, hold N, squeeze N, seed): [row per radius, finest last]}`` with
    ``radius_mm``, ``initial_g``, ``removed_g`` per phase, ``total_g`` and ``total_pct``; runs
    that did not finish (status other than ok) are left out."""
    import polars as pl

    out: dict[tuple[Any, ...], list[dict[str, Any]]] = defaultdict(list)
    for sweep in map(Path, sweeps):
        grid_path, index_path = sweep / "grid.json", sweep / "index.parquet"
        if not grid_path.is_file() or not index_path.is_file():
            raise FileNotFoundError(f"{sweep}: not a finished sweep (grid.json, index.parquet)")
        radius_mm = 1000.0 * float(json.loads(grid_path.read_text())["radius_m"])
        for row in pl.read_parquet(index_path).iter_rows(named=True):
            if row["status"] != "ok":
                continue
            key = (
                int(row["size_cm"]),
                float(row["porosity"]),
                float(row["F_hold"]),
                float(row["F_squeeze"]),
                int(row["seed"]),
            )
            removed = {p: 1000.0 * float(row[f"water_removed_{p}"] or 0.0) for p in PHASES}
            total = sum(removed.values())
            initial = 1000.0 * float(row["initial_water"])
            out[key].append(
                {
                    "radius_mm": radius_mm,
                    "initial_g": initial,
                    "removed_g": removed,
                    "total_g": total,
                    "total_pct": 100.0 * total / initial if initial > 0 else float("nan"),
                }
            )
    for rows in out.values():
        rows.sort(key=lambda r: -r["radius_mm"])
        radii = [r["radius_mm"] for r in rows]
        if len(set(radii)) != len(radii):
            raise ValueError(f"two sweeps at the same radius: {radii} mm")
    return dict(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweeps", nargs="+", help="sweep output directories, one per radius")
    ap.add_argument("--json", action="store_true", help="print the table as JSON")
    a = ap.parse_args(argv)
    try:
        res = load(a.sweeps)
    except (OSError, ValueError) as exc:
        print(f"resolution: {exc}", file=sys.stderr)
        return 2
    if a.json:
        table = [{"condition": list(k), "radii": v} for k, v in res.items()]
        json.dump(table, sys.stdout, indent=1)
        print()
        return 0
    print("water removed per phase (g); total as % of the initial pore water")
    for (size, phi, hold, squeeze, seed), rows in sorted(res.items()):
        print(f"{size} cm, porosity {phi}, holding {hold:g} N, squeeze {squeeze:g} N, seed {seed}")
        print("  r (mm)  initial  " + "  ".join(f"{p:>7s}" for p in PHASES) + "    total")
        for r in rows:
            cells = "  ".join(f"{r['removed_g'][p]:7.1f}" for p in PHASES)
            print(
                f"  {r['radius_mm']:6.1f}  {r['initial_g']:7.1f}  {cells}  "
                f"{r['total_g']:7.1f} ({r['total_pct']:.0f} %)"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
