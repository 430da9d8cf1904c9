"""How much of the 0.64 s water forecast error no world model can remove.

Runs that differ only in the seed of the initial pore-water jitter get the same command
schedule, yet release their water particles at different moments. At every grid time k the
water change over the forecast horizon, D_s(k) = M_L,s(k + H) - M_L,s(k), then differs
between seeds by an amount that the commands cannot explain. Per condition (size, porosity,
holding and squeeze force) it prints, in grams, over the anchors the world-model tables use
(learning phases, the target inside the same run):

- ``baseline``: mean |D_s(k)|, the persistence forecast's error;
- ``floor_in``: mean |D_s(k) - median_s D(k)| over the seeds (the error of the best
  command-only forecast; biased low with few seeds);
- ``floor_loo``: mean |D_s(k) - median of the other seeds' D(k)| (a forecast built from the
  other seeds; biased high);
- ``max_cut``: 1 - floor / baseline for both floors: the largest error reduction against the
  Baseline that any forecast from the commands alone can reach on these runs.

A model also sees the history, which differs between seeds too. ``history R^2`` says how much
of the seed-to-seed spread of D the history explains: the in-sample R^2 of a least-squares
fit of D_s(k) - median_s D(k) on the same deviations of the history features (retained water
now, 0.16 s and 0.32 s ago, saturation, pore volume, force, width; pooled over all groups).

    .venv/bin/rmi sweep --grid studies/grids/study-replicates.json --out results/replicates/sweep
    .venv/bin/python studies/seed_floor.py results/replicates/sweep [--horizon 32] [--json]

Several sweeps may be given (one per grid, e.g. the held-out test groups of the study split,
``studies/grids/test-replicates/*.json``); the per-size lines pool every condition's anchors.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

FEATURES = ("M_L", "S", "V_pore", "F_meas", "w")
LAGS = (0, 8, 16)


Condition = tuple[int, float, float, float]


def condition(row: dict[str, Any]) -> Condition:
    """(size cm, porosity, holding N, squeeze N) of a sweep index row: the runs that share it
    differ only in the seed."""
    return (
        int(row["size_cm"]),
        float(row["porosity"]),
        float(row["F_hold"]),
        float(row["F_squeeze"]),
    )


def _load(sweeps: list[Path]) -> dict[Condition, dict[int, dict[str, np.ndarray]]]:
    import polars as pl

    from rmi_learn.data.dataset import resample_run, select_learning_rows
    from rmi_learn.data.runs import read_run

    groups: dict[Condition, dict[int, dict[str, np.ndarray]]] = defaultdict(dict)
    for sweep in sweeps:
        index = pl.read_parquet(sweep / "index.parquet").filter(pl.col("status") == "ok")
        for row in index.iter_rows(named=True):
            df, _ = read_run(sweep / row["path"])
            r = resample_run(df)
            r["keep"] = select_learning_rows(r["phase"])
            seeds = groups[condition(row)]
            if int(row["seed"]) in seeds:
                raise ValueError(f"{sweep}: {condition(row)} seed {row['seed']} given twice")
            seeds[int(row["seed"])] = r
    return groups


def _deltas(runs: dict[int, dict[str, np.ndarray]], horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """D (seeds x anchors) in kg and history features (seeds x anchors x features) at the grid
    times where every seed has a valid anchor (kept row with its target kept)."""
    common: set[int] | None = None
    for r in runs.values():
        k, keep = r["k"], r["keep"]
        pos = {int(kk): i for i, kk in enumerate(k)}
        ok = {
            int(kk)
            for i, kk in enumerate(k)
            if keep[i]
            and i >= max(LAGS)
            and (int(kk) + horizon) in pos
            and keep[pos[int(kk) + horizon]]
        }
        common = ok if common is None else common & ok
    ks = np.array(sorted(common or ()), dtype=np.int64)
    d, feats = [], []
    for r in runs.values():
        i = np.searchsorted(r["k"], ks)
        m = r["M_L"]
        d.append(m[i + horizon] - m[i])
        feats.append(np.stack([r[f][i - lag] for f in FEATURES for lag in LAGS], axis=-1))
    return np.array(d), np.array(feats)


def errors(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per seed and anchor of ``d`` (seeds x anchors): the Baseline's error |D|, and D's
    signed deviations from the seeds' median and from the median of the other seeds."""
    med = np.median(d, axis=0)
    loo = np.array([np.median(np.delete(d, s, axis=0), axis=0) for s in range(len(d))])
    return np.abs(d), d - med, d - loo


def floors(d: np.ndarray) -> tuple[float, float, float]:
    """(baseline, floor_in, floor_loo) in the units of ``d`` (seeds x anchors)."""
    base, f_in, f_loo = (float(np.mean(e)) for e in _absolute(errors(d)))
    return base, f_in, f_loo


def _absolute(
    errs: tuple[np.ndarray, np.ndarray, np.ndarray],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    base, dev_in, dev_loo = errs
    return base, np.abs(dev_in), np.abs(dev_loo)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("sweep", type=Path, nargs="+", help="rmi sweep outputs with several seeds")
    p.add_argument("--horizon", type=int, default=32, help="steps of 20 ms (32: 0.64 s)")
    p.add_argument("--json", action="store_true", help="one JSON line per group")
    args = p.parse_args()

    groups = _load(args.sweep)
    dev_d, dev_x = [], []
    per_size: dict[int, list[np.ndarray]] = defaultdict(lambda: [np.zeros(0)] * 3)
    print(f"horizon {args.horizon * 0.02:.2f} s; water in g")
    for (size, phi, hold, squeeze), runs in sorted(groups.items()):
        label = f"{size:2d} cm phi {phi:.1f} {hold:3.0f}/{squeeze:3.0f} N"
        if len(runs) < 3:
            print(f"{label}: {len(runs)} seeds, need at least 3")
            continue
        d, x = _deltas(runs, args.horizon)
        if d.shape[1] == 0:
            print(f"{label}: no anchor common to all seeds")
            continue
        errs = errors(d)
        absolute = _absolute(errs)
        base, f_in, f_loo = (float(np.mean(e)) * 1e3 for e in absolute)
        per_size[size] = [
            np.concatenate([a, e.ravel()]) for a, e in zip(per_size[size], absolute, strict=True)
        ]
        dev_d.append(errs[1].ravel())
        dev_x.append((x - np.median(x, axis=0)).reshape(-1, x.shape[-1]))
        rec: dict[str, Any] = {
            "size_cm": size,
            "porosity": phi,
            "F_hold": hold,
            "F_squeeze": squeeze,
            "seeds": len(runs),
            "anchors": int(d.shape[1]),
            "baseline_g": round(base, 2),
            "floor_in_g": round(f_in, 2),
            "floor_loo_g": round(f_loo, 2),
            "max_cut_in": round(1 - f_in / base, 3) if base > 0 else None,
            "max_cut_loo": round(1 - f_loo / base, 3) if base > 0 else None,
        }
        if args.json:
            print(json.dumps(rec))
        else:
            cut = (
                f"max_cut {rec['max_cut_in']:.0%} / {rec['max_cut_loo']:.0%}"
                if base > 0
                else "no water moves"
            )
            print(
                f"{label}: {rec['seeds']} seeds x {rec['anchors']} anchors  "
                f"baseline {base:6.2f}  floor_in {f_in:6.2f}  floor_loo {f_loo:6.2f}  {cut}"
            )
    for size, (b, fi, fl) in sorted(per_size.items()):
        print(
            f"{size:2d} cm, all conditions: baseline {b.mean() * 1e3:6.2f}  "
            f"floor_in {fi.mean() * 1e3:6.2f}  floor_loo {fl.mean() * 1e3:6.2f}  "
            f"max_cut {1 - fi.mean() / b.mean():.0%} / {1 - fl.mean() / b.mean():.0%}"
        )
    if dev_d:
        y = np.concatenate(dev_d)
        xm = np.concatenate(dev_x)
        a = np.column_stack([xm, np.ones(len(y))])
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        resid = y - a @ coef
        r2 = 1.0 - float(resid @ resid) / float(((y - y.mean()) ** 2).sum())
        n_pairs, n_feat = len(y), xm.shape[1]
        print(f"history R^2 (in-sample, {n_pairs} seed-anchor pairs, {n_feat} features): {r2:.3f}")


if __name__ == "__main__":
    main()
