"""Cost of one trial of a paper grid per sponge size on this machine, extrapolated.

A trial of the `paper-fine` grid (r = 2.5 mm) takes 15-60 minutes here, so this times a
number of steps from the start of the trial (settle) and extrapolates to the trial's
simulated duration. Prints one JSON line per size: particle counts, seconds per step, and
the estimated wall time of one trial and runs per hour. (For the `paper` grid, whose trials
take minutes, measure whole trials instead: `benches/grid_time.py`.)

    .venv/bin/python benches/bench_paper_trial.py [--grid paper-fine] [--steps 60] [--threads 2]

Contact phases need somewhat more solver iterations than the settle that is timed, and a lift
failure ends its trial early, so the estimate is good to perhaps +-30 %.
"""

from __future__ import annotations

import argparse
import json
import time

import rmi_sph
from rmi_learn.data.sweep import load_grid, size_overrides

# Simulated time the controller spends closing and lifting (s); the other phases have fixed
# durations in the config.
CLOSE_S, LIFT_S = 0.3, 0.5


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=60)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--grid", default="paper-fine", choices=("paper", "paper-fine"))
    args = ap.parse_args()
    grid = load_grid(args.grid)
    for size in grid["sizes_cm"]:
        overrides = size_overrides(grid, size)
        cfg = rmi_sph.trial_config(size, 0.6, 110.0, 200.0, grid["radius_m"], **overrides)
        sim = rmi_sph.Trial(cfg, num_threads=args.threads)
        sim.step(5)  # first steps build caches and warm starts
        t0 = time.perf_counter()
        sim.step(args.steps)
        per_step = (time.perf_counter() - t0) / args.steps
        c = cfg["controller"]
        duration = sum(
            c[k]
            for k in (
                "settle_time",
                "ramp_time",
                "hold_time",
                "wait_time",
                "squeeze_ramp_time",
                "squeeze_hold_time",
            )
        )
        duration += CLOSE_S + LIFT_S
        trial_s = per_step * duration / sim.dt
        print(
            json.dumps(
                {
                    "size_cm": size,
                    "fluid": int(sim.particles("fluid")["mass"].shape[0]),
                    "solid": int(sim.particles("solid")["mass"].shape[0]),
                    "dt": sim.dt,
                    "s_per_step": round(per_step, 4),
                    "trial_sim_s": duration,
                    "trial_wall_min": round(trial_s / 60, 1),
                    "runs_per_hour": round(3600 / trial_s, 2),
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
