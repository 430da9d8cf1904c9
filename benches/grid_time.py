"""Wall time of a whole sweep grid, extrapolated from a measured sample of its runs.

Reads a finished sample sweep (``index.parquet``: each run's size and wall time), takes the
mean trial time per sponge size, gives every run of the target grid its size's mean, and
schedules the grid's jobs longest first on N workers (each job to the worker that frees
first, as ``rmi sweep`` does): the predicted wall time per worker count. A job is a group of
runs that differ only in their squeeze force (``rmi sweep`` runs each group from one shared
prefix, ``rmi_learn.data.sweep.prefix_groups``), and a run's recorded wall time is its share
of that prefix plus its own squeeze: so the sample must hold the grid's squeeze forces for
its per-run times to be the grid's. A worker is one trial process on its own core
(``--threads-per-run 1``), so the sample must be measured that way, e.g. on a 2-core machine
with ``--workers 2 --threads-per-run 1``; then N workers are N such cores, on one machine or
on several through Ray.

    rmi sweep --grid studies/grids/paper-sample.json --out results/paper-sample \\
        --workers 2 --threads-per-run 1
    python benches/grid_time.py results/paper-sample --grid paper --workers 1 2 4 8 16 32

A sponge dropped at a low holding force ends its trial early; the sample's share of such runs
need not be the grid's, so ``--lifted-only`` gives the upper bound where no run drops.
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys
from pathlib import Path


def mean_time_by_size(index_path: str | Path, lifted_only: bool = False) -> dict[int, float]:
    """Mean wall time (s) of the sample's finished runs per sponge size (cm); with
    ``lifted_only``, of the runs that lifted the sponge (a dropped sponge ends its trial early,
    so this is the cost if no run of the grid drops it)."""
    import polars as pl

    runs = pl.scan_parquet(index_path).filter(
        pl.col("status").is_in(["ok", "unstable"]) & pl.col("wall_s").is_not_null()
    )
    if lifted_only:
        runs = runs.filter(pl.col("lift_success"))
    means = runs.group_by("size_cm").agg(pl.col("wall_s").mean()).sort("size_cm").collect()
    return {int(s): float(t) for s, t in means.iter_rows()}


def makespan(times: list[float], workers: int) -> float:
    """Wall time (s) of running ``times`` longest first, each on the worker that frees first."""
    if workers < 1:
        raise ValueError("workers must be at least 1")
    free = [0.0] * workers
    for t in sorted(times, reverse=True):
        heapq.heapreplace(free, free[0] + t)
    return max(free)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sample", help="a finished sweep of some of the grid's runs")
    ap.add_argument("--grid", default="paper", help="grid preset or JSON file to extrapolate to")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32])
    ap.add_argument(
        "--lifted-only",
        action="store_true",
        help="time per size from the runs that lifted the sponge (no early ends): an upper bound",
    )
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    a = ap.parse_args(argv)
    from rmi_learn.data.sweep import PRESETS, configs_of, expand_grid, load_grid, prefix_groups

    try:
        index = Path(a.sample) / "index.parquet"
        if not index.is_file():
            raise FileNotFoundError(f"{a.sample}: not a finished sweep (no index.parquet)")
        per_size = mean_time_by_size(index, a.lifted_only)
        grid = load_grid(a.grid) if a.grid in PRESETS else load_grid(path=a.grid)
        specs = expand_grid(grid)
        missing = sorted({s.params["size_cm"] for s in specs} - set(per_size))
        if missing:
            raise ValueError(f"the sample has no finished run of size {missing} cm")
        if any(w < 1 for w in a.workers):
            raise ValueError("--workers: expected integers >= 1")
        groups = prefix_groups(specs, configs_of(specs))
        sample_grid = Path(a.sample) / "grid.json"
        forces = None
        if sample_grid.is_file():
            forces = json.loads(sample_grid.read_text()).get("squeeze_forces_N")
    except (OSError, ValueError) as exc:
        print(f"grid_time: {exc}", file=sys.stderr)
        return 2
    jobs = [sum(per_size[s.params["size_cm"]] for s in g) for g in groups]
    if forces is not None and sorted(forces) != sorted(grid["squeeze_forces_N"]):
        print(
            f"grid_time: the sample's squeeze forces {forces} are not the grid's "
            f"{grid['squeeze_forces_N']}: its runs share their prefixes differently, so the "
            "per-run times are only approximate",
            file=sys.stderr,
        )
    rows = [{"workers": w, "wall_h": makespan(jobs, w) / 3600.0} for w in a.workers]
    result = {
        "grid": grid.get("name", a.grid),
        "runs": len(specs),
        "jobs": len(groups),
        "mean_trial_s_by_size": per_size,
        "cpu_hours": sum(jobs) / 3600.0,
        "wall": rows,
    }
    if a.json:
        print(json.dumps(result, indent=1))
        return 0
    sizes = ", ".join(f"{s} cm {t:.0f} s" for s, t in per_size.items())
    print(
        f"grid {result['grid']}: {len(specs)} runs in {len(groups)} jobs; mean trial {sizes}; "
        f"{result['cpu_hours']:.1f} trial-hours"
    )
    for r in rows:
        print(f"  {r['workers']:4d} workers: {r['wall_h']:7.2f} h")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
