"""How loose may the implicit solve's tolerance be before a trial's observables move?

Runs ``paper`` grid trials (its radius, per-size time steps and phase timings; porosity 0.6,
seed 0) for each sponge size and holding / squeeze force pair at several ``cg.tolerance``
values, and tabulates per condition the water removed in all, the largest deviation of any
phase's water and of the total from the tightest tolerance (both as a fraction of the tightest
run's total, as in ``convergence.py``), the peak grip force, lift success and the wall time.

    python studies/cg_tolerance.py run --out results/cg-tolerance --sizes 8 10 12 \\
        --forces 10/50 110/300 210/300 --tolerances 1e-4 3e-3 1e-2 --jobs 2
    python studies/cg_tolerance.py table results/cg-tolerance [--json]

With ``--jobs 2`` two trials share the machine, so the wall times compare tolerances only
roughly; benchmark speed side by side (docs/benchmark-history.md, "The implicit solve's
tolerance"). Finished trials are JSON files under OUT (written atomically) and are skipped
when the command runs again.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

from convergence import PHASES, _write_atomic, observables


def trial_name(size_cm: int, hold: float, squeeze: float, tol: float) -> str:
    """File stem of one trial, e.g. ``s8-110N-300N-tol0.003``."""
    return f"s{size_cm}-{hold:g}N-{squeeze:g}N-tol{tol:g}"


def config_of(job: dict[str, Any]) -> dict[str, Any]:
    """The trial config of one job (the engine validates it): the ``paper`` grid's radius and
    overrides for the job's size (set by :func:`run`), with the job's CG tolerance."""
    import rmi_sph

    return dict(
        rmi_sph.trial_config(
            job["size_cm"],
            0.6,
            job["hold_N"],
            job["squeeze_N"],
            job["radius_m"],
            0,
            cg={"tolerance": job["tolerance"]},
            **job["overrides"],
        )
    )


def _run_one(job: dict[str, Any]) -> dict[str, Any]:
    import rmi_sph

    cfg = config_of(job)
    t0 = time.perf_counter()
    res = rmi_sph.run_trial(cfg, num_threads=1)
    return {
        **job,
        "wall_s": time.perf_counter() - t0,
        **observables(res["outcome"], res["columns"]),
    }


def run(args: argparse.Namespace) -> int:
    from rmi_learn.data.sweep import load_grid, size_overrides

    out = Path(args.out)
    grid = load_grid("paper")
    jobs = []
    for size in args.sizes:
        paper = {"radius_m": grid["radius_m"], "overrides": size_overrides(grid, size)}
        for pair in args.forces:
            hold, squeeze = (float(x) for x in pair.split("/"))
            for tol in args.tolerances:
                path = out / f"{trial_name(size, hold, squeeze, tol)}.json"
                if not path.is_file():
                    job = {"size_cm": size, "hold_N": hold, "squeeze_N": squeeze, **paper}
                    jobs.append({**job, "tolerance": tol, "path": str(path)})
    for j in jobs:
        config_of(j)  # every config is checked before the first trial starts
    jobs.sort(key=lambda j: (-j["size_cm"], j["tolerance"]))
    out.mkdir(parents=True, exist_ok=True)
    print(f"{len(jobs)} trials to run, {args.jobs} at a time on one thread each", flush=True)
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=args.jobs, mp_context=ctx) as pool:
        for fut in cf.as_completed([pool.submit(_run_one, j) for j in jobs]):
            rec = fut.result()
            path = Path(rec.pop("path"))
            _write_atomic(path, rec)
            print(f"{path.stem}: {rec['wall_s']:.0f} s", flush=True)
    return 0


def compare(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per condition, each tolerance's figures against the tightest tolerance's."""
    groups: dict[tuple[int, float, float], list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        groups[(r["size_cm"], r["hold_N"], r["squeeze_N"])].append(r)
    rows = []
    for key in sorted(groups):
        series = sorted(groups[key], key=lambda r: r["tolerance"])
        ref = series[0]
        scale = max(abs(ref["total_g"]), 1e-9)
        for r in series:
            phase_dev = max(abs(r["removed_g"][p] - ref["removed_g"][p]) for p in PHASES)
            rows.append(
                {
                    "size_cm": key[0],
                    "hold_N": key[1],
                    "squeeze_N": key[2],
                    "tolerance": r["tolerance"],
                    "total_g": r["total_g"],
                    "total_dev": (r["total_g"] - ref["total_g"]) / scale,
                    "max_phase_dev": phase_dev / scale,
                    "peak_force_N": r["peak_force_N"],
                    "lift_success": r["lift_success"],
                    "same_lift": r["lift_success"] == ref["lift_success"],
                    "wall_s": r["wall_s"],
                    "speed_vs_tightest": ref["wall_s"] / r["wall_s"],
                }
            )
    return rows


def table(args: argparse.Namespace) -> int:
    records = [json.loads(p.read_text()) for p in sorted(Path(args.out).glob("*.json"))]
    rows = compare(records)
    if args.json:
        print(json.dumps(rows, indent=1))
        return 0
    print(
        "| sponge | hold / squeeze | cg.tolerance | water (g) | total dev. | largest phase dev. "
        "| peak force (N) | lifted | wall (s) | speed |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['size_cm']} cm | {r['hold_N']:g} / {r['squeeze_N']:g} N | {r['tolerance']:g} "
            f"| {r['total_g']:.2f} | {100 * r['total_dev']:+.2f} % "
            f"| {100 * r['max_phase_dev']:.2f} % "
            f"| {r['peak_force_N']:.1f} | {'yes' if r['lift_success'] else 'no'} "
            f"| {r['wall_s']:.0f} | {r['speed_vs_tightest']:.2f}x |"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the trials (resumable)")
    r.add_argument("--out", required=True)
    r.add_argument("--sizes", type=int, nargs="+", default=[8, 10, 12])
    r.add_argument(
        "--forces",
        nargs="+",
        default=["10/50", "110/300", "210/300"],
        help="holding / squeeze force pairs (N)",
    )
    r.add_argument("--tolerances", type=float, nargs="+", default=[1e-4, 3e-3, 1e-2])
    r.add_argument("--jobs", type=int, default=2)
    t = sub.add_parser("table", help="tabulate a finished series")
    t.add_argument("out")
    t.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    return run(args) if args.cmd == "run" else table(args)


if __name__ == "__main__":
    sys.exit(main())
