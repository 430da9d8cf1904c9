"""Water removed per phase of single trials, for comparing engine settings side by side.

Each positional argument is a JSON object of trial settings: ``size`` (cm), ``phi``, ``hold``
and ``squeeze`` (N), and any ``rmi_sph.trial_config`` override (``pressure``, ``material``,
...). The study grid's timings at r = 8 mm are the defaults. Prints one line per trial:
retained water at start and end, grams removed per phase, wall time.

    python studies/phase_water.py '{"phi": 0.5, "hold": 100, "squeeze": 300}' \
        '{"phi": 0.5, "hold": 100, "squeeze": 300, "pressure": {"drag_coupled": false}}'
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import rmi_sph
from rmi_learn.data.sweep import load_grid

#: The study grid's dt and phase timings, read from its preset.
STUDY_TIMING: dict[str, Any] = load_grid("study")["overrides"]


def removed_per_phase(spec: dict[str, Any], threads: int) -> str:
    s = dict(spec)
    size, phi = s.pop("size", 8), s.pop("phi", 0.6)
    hold, squeeze = s.pop("hold", 100.0), s.pop("squeeze", 100.0)
    radius = s.pop("radius", 0.008)
    cfg = rmi_sph.trial_config(size, phi, hold, squeeze, radius=radius, **{**STUDY_TIMING, **s})
    t0 = time.perf_counter()
    out = rmi_sph.run_trial(cfg, num_threads=threads)
    wall = time.perf_counter() - t0
    col = out["columns"]
    water = col["M_L"] * 1e3
    first: dict[str, float] = {}
    last: dict[str, float] = {}
    for phase, m in zip(col["phase"], water, strict=True):
        first.setdefault(str(phase), float(m))
        last[str(phase)] = float(m)
    phases = " ".join(f"{p} {first[p] - last[p]:+.0f}" for p in first)
    return (
        f"{json.dumps(spec)}: M_L {water[0]:.0f} -> {water[-1]:.0f} g | {phases} | "
        f"lift ok {out['outcome'].get('lift_success')} | {wall:.1f} s"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("trials", nargs="+", help="JSON object per trial")
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    for spec in a.trials:
        print(removed_per_phase(json.loads(spec), a.threads), flush=True)


if __name__ == "__main__":
    main()
