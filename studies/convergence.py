"""At which particle radius and time step are a trial's observables converged?

Runs one grasp-lift-squeeze condition (by default porosity 0.6, holding 100 N, squeeze 300 N,
seed 0, with the phase timings of the ``paper`` grid) for each sponge size at several particle
radii and time steps, and tabulates per size and dt the water removed in each controller phase
and in all, the peak grip force and whether the lift held, each with its deviation from the
finest radius of that size and dt. The coarsest radius from which every finer one stays within
``--tolerance`` of the finest is reported as converged:

- water (per phase and in all): ``|removed(r) - removed(finest)| <= tolerance x total(finest)``,
  measured against the finest trial's total so that a phase which removes almost nothing
  cannot decide alone;
- peak grip force: ``|F(r) - F(finest)| <= tolerance x F(finest)``;
- lift success: the same as the finest.

The finest radius of a series is its reference, not a proof of convergence: read the table's
trend too. Each finished trial is one JSON file under OUT (written atomically); running again
skips it, so an interrupted series resumes. Trials run in spawned worker processes (the engine
owns a thread pool per trial), the most expensive first.

    python studies/convergence.py run --out results/convergence --sizes 8 --radii 8 6.5 5 4 \\
        --dts 0.001 0.002 --jobs 1 --threads 2
    python studies/convergence.py table results/convergence [--tolerance 0.05] [--json]

The controller's contact debounce, slip-out count and gate count are in simulator steps and
its load filter acts per step (as the paper states them), so by default each dt also runs a
controller with other time constants; ``--controller-dt 0.002`` holds them at the times they
span at dt = 2 ms, so that only the engine's time step differs.

Running needs only ``rmi_sph`` (no polars, no torch): the series can run on any machine that
imports the module.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import copy
import json
import math
import multiprocessing
import os
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

#: Controller phases whose removed water is an observable, in trial order.
PHASES = ("ramp", "hold", "lift", "waiting", "squeeze")
#: Grid presets whose phase timings a series can use (their ``overrides`` minus ``dt``). Read
#: as files rather than through ``rmi_learn.data.sweep.load_grid``, which needs polars.
GRIDS = Path(__file__).resolve().parents[1] / "python" / "rmi_learn" / "data" / "grids"


def timings(preset: str) -> dict[str, float]:
    """The phase timings (s) of a grid preset (``paper``, ``study``, ...), without its dt."""
    path = GRIDS / f"{preset}.json"
    if not path.is_file():
        known = sorted(p.stem for p in GRIDS.glob("*.json"))
        raise ValueError(f"--timings: no grid preset {preset!r}; expected one of {known}")
    overrides = dict(json.loads(path.read_text()).get("overrides", {}))
    overrides.pop("dt", None)
    return {k: float(v) for k, v in overrides.items()}


def trial_name(size_cm: int, radius_mm: float, dt_s: float) -> str:
    """File stem of one trial of a series, e.g. ``s8-r6.5mm-dt1ms``."""
    return f"s{size_cm}-r{radius_mm:g}mm-dt{1000.0 * dt_s:g}ms"


def relative_cost(size_cm: int, radius_mm: float, dt_s: float) -> float:
    """Estimated cost of a trial relative to the others (sponge volume / r^3 / dt, i.e.
    particles x steps): used only to start the most expensive first."""
    import rmi_sph

    volume = {round(100 * d[0]): d[0] * d[1] * d[2] for d in rmi_sph.SPONGE_SIZES_M}
    return volume[size_cm] / radius_mm**3 / dt_s


def observables(outcome: dict[str, Any], columns: dict[str, Any]) -> dict[str, Any]:
    """The trial's observables from ``rmi_sph.run_trial``'s outcome and columns: water
    removed per phase and in all (g), peak grip force (N), lift success, and the cost."""
    removed = outcome.get("water_removed") or {}
    per_phase = {p: 1000.0 * float(removed.get(p, 0.0) or 0.0) for p in PHASES}
    forces = [float(f) for f in columns["F_meas"] if math.isfinite(float(f))]
    return {
        "removed_g": per_phase,
        "total_g": sum(per_phase.values()),
        "initial_g": 1000.0 * float(outcome["initial_water"]),
        "peak_force_N": max(forces) if forces else float("nan"),
        "lift_success": bool(outcome["lift_success"]),
        "failure": outcome.get("failure"),
        "steps": int(outcome["steps"]),
        "particles": int(outcome["n_fluid"]) + int(outcome["n_solid"]),
    }


#: The controller's and the gate's parameters counted in simulator steps (section, field).
STEP_COUNTS = (("controller", "k_contact"), ("controller", "k_lost"), ("gate", "k_stable"))


def hold_controller_times(cfg: dict[str, Any], dt_ref: float) -> dict[str, Any]:
    """``cfg`` (a trial config) with the controller's step counts and the gate's per-step load
    filter rescaled to span, at ``cfg["dt"]``, the times they span at ``dt_ref`` (s): each count
    times ``dt_ref / dt`` (rounded, at least 1), and ``eta_f`` such that the filter's decay per
    second is the same. As configured, a trial at another dt runs a controller with other time
    constants as well as another time step."""
    scale = dt_ref / float(cfg["dt"])
    out = copy.deepcopy(cfg)
    if scale == 1.0:
        return out
    for section, field in STEP_COUNTS:
        out[section][field] = max(1, round(cfg[section][field] * scale))
    out["gate"]["eta_f"] = 1.0 - (1.0 - cfg["gate"]["eta_f"]) ** (1.0 / scale)
    return out


def config_of(job: dict[str, Any]) -> dict[str, Any]:
    """The trial config of one job of the series (the engine validates it)."""
    import rmi_sph

    cfg = dict(
        rmi_sph.trial_config(
            job["size_cm"],
            job["porosity"],
            job["hold_N"],
            job["squeeze_N"],
            job["radius_mm"] / 1000.0,
            job["seed"],
            dt=job["dt_s"],
            **job["timings"],
        )
    )
    if job.get("controller_dt_s"):
        cfg = hold_controller_times(cfg, job["controller_dt_s"])
    return cfg


def _run_one(job: dict[str, Any]) -> dict[str, Any]:
    """Worker: one trial of the series, its observables and wall time (s)."""
    import rmi_sph

    cfg = config_of(job)
    t0 = time.perf_counter()
    try:
        res = rmi_sph.run_trial(cfg, num_threads=job["threads"])
    except (rmi_sph.SimulationUnstableError, rmi_sph.StateError) as exc:
        return {**job, "status": "unstable", "error": str(exc), "wall_s": time.perf_counter() - t0}
    return {
        **job,
        "status": "ok",
        "wall_s": time.perf_counter() - t0,
        **observables(res["outcome"], res["columns"]),
    }


def _write_atomic(path: Path, record: dict[str, Any]) -> None:
    # Not rmi_learn.data.runs.atomic_write_json: that module needs polars, which the machine
    # running a series may lack.
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    os.replace(tmp, path)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    base = {
        "porosity": args.porosity,
        "hold_N": args.hold,
        "squeeze_N": args.squeeze,
        "seed": args.seed,
        "timings_preset": args.timings,
        "timings": timings(args.timings),
        "threads": args.threads,
        "controller_dt_s": args.controller_dt,
    }
    jobs = []
    for size in args.sizes:
        for r in args.radii:
            for dt in args.dts:
                path = out / f"{trial_name(size, r, dt)}.json"
                if path.is_file():
                    continue
                jobs.append(
                    {**base, "size_cm": size, "radius_mm": r, "dt_s": dt, "path": str(path)}
                )
    import rmi_sph

    for j in jobs:
        # Every config is checked before the first trial starts.
        try:
            config_of(j)
        except rmi_sph.ConfigError as exc:
            raise ValueError(f"{Path(j['path']).stem}: {exc}") from exc
    jobs.sort(key=lambda j: -relative_cost(j["size_cm"], j["radius_mm"], j["dt_s"]))
    out.mkdir(parents=True, exist_ok=True)
    print(
        f"{len(jobs)} trials to run, {args.jobs} at a time on {args.threads} threads each",
        flush=True,
    )
    ctx = multiprocessing.get_context("spawn")
    with cf.ProcessPoolExecutor(max_workers=args.jobs, mp_context=ctx) as pool:
        pending = {pool.submit(_run_one, j): j for j in jobs}
        for fut in cf.as_completed(pending):
            rec = fut.result()
            path = Path(rec.pop("path"))
            _write_atomic(path, rec)
            print(f"{path.stem}: {rec['status']}, {rec['wall_s']:.0f} s", flush=True)
    return 0


def load(out: str | Path) -> list[dict[str, Any]]:
    """Every finished trial record of a series directory."""
    return [json.loads(p.read_text()) for p in sorted(Path(out).glob("*.json"))]


def _check(value: float, ref: float, scale: float, tol: float) -> tuple[float, bool]:
    """Deviation of ``value`` from ``ref`` as a fraction of ``scale``; whether within ``tol``."""
    if not (math.isfinite(value) and math.isfinite(ref)) or scale <= 0.0:
        return float("nan"), False
    dev = (value - ref) / scale
    return dev, abs(dev) <= tol


def converge(records: list[dict[str, Any]], tolerance: float) -> list[dict[str, Any]]:
    """Per (size, dt) series, finest radius first: each radius's observables, their deviations
    from the finest and whether they pass (see the module's docstring), and the converged
    radius (None when only the finest passes, or the series has a single radius)."""
    by_series: dict[tuple[int, float], list[dict[str, Any]]] = defaultdict(list)
    for rec in records:
        by_series[(int(rec["size_cm"]), float(rec["dt_s"]))].append(rec)
    table = []
    for (size, dt), recs in sorted(by_series.items()):
        recs.sort(key=lambda r: r["radius_mm"])
        ok = [r for r in recs if r.get("status") == "ok"]
        rows: list[dict[str, Any]] = []
        converged: float | None = None
        if ok:
            fine = ok[0]
            total = float(fine["total_g"])
            chain = True  # every finer radius passed
            for r in recs:
                if r.get("status") != "ok":
                    rows.append(
                        {"radius_mm": r["radius_mm"], "status": r.get("status"), "passes": False}
                    )
                    chain = False
                    continue
                devs: dict[str, float] = {}
                passes = bool(r["lift_success"]) == bool(fine["lift_success"])
                for p in PHASES:
                    devs[p], good = _check(
                        r["removed_g"][p], fine["removed_g"][p], total, tolerance
                    )
                    passes &= good
                devs["total"], good = _check(r["total_g"], total, total, tolerance)
                passes &= good
                devs["peak_force"], good = _check(
                    r["peak_force_N"], fine["peak_force_N"], fine["peak_force_N"], tolerance
                )
                passes &= good
                chain &= passes
                if chain and r is not fine:
                    converged = float(r["radius_mm"])
                rows.append({**r, "deviation": devs, "passes": passes})
        table.append({"size_cm": size, "dt_s": dt, "rows": rows, "converged_radius_mm": converged})
    return table


def _print_table(table: list[dict[str, Any]], tolerance: float) -> None:
    print(
        "initial pore water and water removed per phase and in all (g), peak grip force (N); "
        "dev = deviation from the finest radius (water: of its total); share = the total as "
        f"% of the initial water; tolerance {100 * tolerance:g} %"
    )
    for s in table:
        conv = s["converged_radius_mm"]
        verdict = (
            f"converged from r = {conv:g} mm"
            if conv is not None
            else "no coarser radius within tolerance"
        )
        print(f"\n{s['size_cm']} cm sponge, dt = {1000 * s['dt_s']:g} ms: {verdict}")
        head = "  r (mm)  particles  initial  " + "  ".join(f"{p:>7s}" for p in PHASES)
        print(head + "    total   dev %  share %  F_peak  dev %  lift  wall s")
        for r in s["rows"]:
            if r.get("status") != "ok":
                print(f"  {r['radius_mm']:6.2f}  {r.get('status')}")
                continue
            cells = "  ".join(f"{r['removed_g'][p]:7.2f}" for p in PHASES)
            d = r["deviation"]
            print(
                f"  {r['radius_mm']:6.2f}  {r['particles']:9d}  {r['initial_g']:7.1f}  {cells}  "
                f"{r['total_g']:7.2f}  "
                f"{100 * d['total']:+6.1f}  {100 * r['total_g'] / r['initial_g']:7.2f}  "
                f"{r['peak_force_N']:6.1f}  "
                f"{100 * d['peak_force']:+5.1f}  "
                f"{'yes' if r['lift_success'] else 'no':>4s}  {r['wall_s']:6.0f}"
                + ("" if r["passes"] else "  (outside)")
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the series' missing trials")
    r.add_argument("--out", required=True, help="series directory (one JSON file per trial)")
    r.add_argument("--sizes", type=int, nargs="+", default=[8], choices=(8, 10, 12), help="cm")
    r.add_argument(
        "--radii", type=float, nargs="+", default=[8.0, 6.5, 5.0, 4.0], help="particle radii (mm)"
    )
    r.add_argument("--dts", type=float, nargs="+", default=[0.001, 0.002], help="time steps (s)")
    r.add_argument("--porosity", type=float, default=0.6)
    r.add_argument("--hold", type=float, default=100.0, help="holding force (N)")
    r.add_argument("--squeeze", type=float, default=300.0, help="squeeze force (N)")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--timings", default="paper", help="grid preset whose phase timings to use")
    r.add_argument("--jobs", type=int, default=1, help="trials at a time")
    r.add_argument("--threads", type=int, default=2, help="engine threads per trial")
    r.add_argument(
        "--controller-dt",
        type=float,
        default=None,
        metavar="SECONDS",
        help="hold the controller's step counts and its per-step load filter at the times they "
        "span at this time step, so that only the engine's time step differs between dts "
        "(default: as configured, in steps)",
    )
    t = sub.add_parser("table", help="tabulate a series and its converged radius")
    t.add_argument("out", help="series directory")
    t.add_argument(
        "--tolerance", type=float, default=0.05, help="fraction of the finest (default 0.05)"
    )
    t.add_argument("--json", action="store_true", help="print the table as JSON")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "run":
            if a.jobs < 1 or a.threads < 1:
                raise ValueError("--jobs and --threads: expected integers >= 1")
            if any(not (0.5 <= x <= 20.0) for x in a.radii):
                raise ValueError("--radii: expected particle radii in [0.5, 20] mm")
            if a.controller_dt is not None and not (1e-5 <= a.controller_dt <= 0.1):
                raise ValueError(f"--controller-dt: {a.controller_dt} s is not in [1e-5, 0.1] s")
            return run(a)
        if not 0.0 < a.tolerance < 1.0:
            raise ValueError(f"--tolerance: {a.tolerance} is not in (0, 1)")
        table = converge(load(a.out), a.tolerance)
    except (OSError, ValueError) as exc:
        print(f"convergence: {exc}", file=sys.stderr)
        return 2
    if not a.json:
        _print_table(table, a.tolerance)
        return 0
    print(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
