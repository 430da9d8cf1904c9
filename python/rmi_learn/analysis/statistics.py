"""The numbers of the physical analysis, from a run table's index: run counts, water removed
per controller phase, lift success over the grid and the within-group association of squeeze
force with squeeze-phase water removal (with its cluster bootstrap and sandwich intervals).
Masses are stored in kg and reported in g."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import polars as pl

from rmi_learn.analysis.run_table import ANALYSIS_PHASES, ok_runs, reached_mask

#: Runs sharing these values form one matched group for the squeeze association.
GROUP_KEYS: tuple[str, ...] = ("size_cm", "porosity", "F_hold", "seed")
G_PER_KG = 1e3
DEFAULT_BOOTSTRAP = 2000
#: Below this many informative groups the association carries a ``caution``.
FEW_GROUPS = 10


def _bool_count(series: pl.Series) -> int:
    return int(series.fill_null(False).sum())


def run_counts(index: pl.DataFrame) -> dict[str, Any]:
    """Runs in total and by status, and among ``ok`` runs the lift successes and stable
    squeezes, overall and per sponge size."""
    status = index["status"].to_list()
    ok = ok_runs(index)
    by_size: dict[str, dict[str, int]] = {}
    for size in sorted({int(s) for s in index["size_cm"].to_list()}):
        sub = index.filter(pl.col("size_cm") == size)
        oks = ok_runs(sub)
        by_size[str(size)] = {
            "runs": sub.height,
            "ok": oks.height,
            "lift_success": _bool_count(oks["lift_success"]),
            "stable_squeeze": _bool_count(oks["stable_squeeze"]),
        }
    return {
        "runs_total": index.height,
        "ok": status.count("ok"),
        "failed": status.count("failed"),
        "unstable": status.count("unstable"),
        "other_status": sum(1 for s in status if s not in ("ok", "failed", "unstable")),
        "lift_success": _bool_count(ok["lift_success"]),
        "stable_squeeze": _bool_count(ok["stable_squeeze"]),
        "lift_and_stable_squeeze": _bool_count(ok["lift_success"] & ok["stable_squeeze"]),
        "by_size": by_size,
    }


def water_per_phase(index: pl.DataFrame) -> dict[str, Any]:
    """Water removed in each phase of :data:`ANALYSIS_PHASES` (g) over the ``ok`` runs that
    reached it: count, median, quartiles, extremes and how many are negative (water taken
    back up or counted back). ``median_fraction`` is the median over runs that reached
    every phase of each phase's share of their summed removal (runs whose sum is not
    positive are left out); medians of shares need not sum to 1. ``pooled_fraction`` is the
    phase's share of the summed removal of those runs, which does sum to 1."""
    ok = ok_runs(index)
    per_phase: dict[str, Any] = {}
    values: dict[str, np.ndarray] = {}
    reached_all = np.ones(ok.height, dtype=bool)
    for ph in ANALYSIS_PHASES:
        mask = reached_mask(ok, ph)
        reached_all &= mask
        g = ok[f"water_removed_{ph}"].fill_null(float("nan")).to_numpy()[mask] * G_PER_KG
        values[ph] = g
        per_phase[ph] = _describe(g)
    mat = np.stack(
        [ok[f"water_removed_{ph}"].fill_null(0.0).to_numpy() for ph in ANALYSIS_PHASES], axis=1
    )[reached_all]
    total = mat.sum(axis=1)
    positive = total > 0
    median_fraction: dict[str, float | None] = {}
    pooled_fraction: dict[str, float | None] = {}
    pooled_total = float(mat[positive].sum())
    for j, ph in enumerate(ANALYSIS_PHASES):
        share = mat[positive, j] / total[positive]
        median_fraction[ph] = float(np.median(share)) if share.size else None
        pooled_fraction[ph] = (
            float(mat[positive, j].sum() / pooled_total) if pooled_total > 0 else None
        )
    return {
        "unit": "g",
        "phases": list(ANALYSIS_PHASES),
        "per_phase": per_phase,
        "n_runs_all_phases": int(reached_all.sum()),
        "n_runs_fraction": int(positive.sum()),
        "median_fraction": median_fraction,
        "pooled_fraction": pooled_fraction,
        "_values_g": values,
    }


def _describe(g: np.ndarray) -> dict[str, Any]:
    if g.size == 0:
        return {
            "n": 0,
            "median": None,
            "q1": None,
            "q3": None,
            "min": None,
            "max": None,
            "n_negative": 0,
        }
    q1, med, q3 = np.quantile(g, [0.25, 0.5, 0.75])
    return {
        "n": int(g.size),
        "median": float(med),
        "q1": float(q1),
        "q3": float(q3),
        "min": float(g.min()),
        "max": float(g.max()),
        "n_negative": int((g < 0).sum()),
    }


def lift_success_table(index: pl.DataFrame) -> dict[str, Any]:
    """Lift success over (size, porosity, holding force) among ``ok`` runs, pooled over
    squeeze forces and seeds: ``cells`` (``n``, ``n_success``, ``rate``), the rate per size
    and porosity, and per size and porosity the smallest holding force (N) with at least
    one success and the smallest with every run successful (``None`` if there is none).
    ``F_hold_values`` / ``porosities`` list the grid's values, so a cell missing from
    ``cells`` had no run."""
    ok = ok_runs(index).filter(pl.col("lift_success").is_not_null())
    sizes = sorted({int(s) for s in ok["size_cm"].to_list()})
    porosities = sorted({float(p) for p in ok["porosity"].to_list()})
    holds = sorted({float(f) for f in ok["F_hold"].to_list()})
    cells: list[dict[str, Any]] = []
    by_sp: list[dict[str, Any]] = []
    for (size, por, hold), sub in groups_by(ok, ("size_cm", "porosity", "F_hold")):
        n = sub.height
        k = _bool_count(sub["lift_success"])
        cells.append(
            {
                "size_cm": size,
                "porosity": por,
                "F_hold": hold,
                "n": n,
                "n_success": k,
                "rate": k / n,
            }
        )
    for size in sizes:
        for por in porosities:
            mine = [c for c in cells if c["size_cm"] == size and c["porosity"] == por]
            if not mine:
                continue
            n = sum(c["n"] for c in mine)
            k = sum(c["n_success"] for c in mine)
            any_ok = [c["F_hold"] for c in mine if c["n_success"] > 0]
            all_ok = [c["F_hold"] for c in mine if c["n_success"] == c["n"]]
            by_sp.append(
                {
                    "size_cm": size,
                    "porosity": por,
                    "n": n,
                    "n_success": k,
                    "rate": k / n,
                    "min_F_hold_any_success": min(any_ok) if any_ok else None,
                    "min_F_hold_all_success": min(all_ok) if all_ok else None,
                }
            )
    return {
        "sizes_cm": sizes,
        "porosities": porosities,
        "F_hold_values": holds,
        "cells": cells,
        "by_size_porosity": by_sp,
    }


def groups_by(df: pl.DataFrame, keys: Sequence[str]) -> list[tuple[tuple[Any, ...], pl.DataFrame]]:
    """Sub-frames of ``df`` per distinct value of ``keys``, in sorted key order."""
    if df.height == 0:
        return []
    out = [(tuple(k), g) for k, g in df.group_by(list(keys), maintain_order=True)]
    return sorted(out, key=lambda kg: kg[0])


def t_critical(df: int, level: float = 0.95) -> float:
    """Two-sided critical value of Student's t with ``df`` (>= 1) degrees of freedom, from
    the closed-form distribution function for integer ``df`` (no SciPy needed)."""
    if df < 1:
        raise ValueError("t_critical needs df >= 1")

    def central(t: float) -> float:  # P(|T| < t)
        theta = math.atan(t / math.sqrt(df))
        s, c2 = math.sin(theta), math.cos(theta) ** 2
        if df % 2 == 1:
            term, acc = 1.0, 0.0
            if df > 1:
                term = math.cos(theta)
                acc = term
                for k in range(3, df - 1, 2):
                    term *= c2 * (k - 1) / k
                    acc += term
            return 2.0 / math.pi * (theta + s * acc)
        term, acc = 1.0, 1.0
        for k in range(2, df - 1, 2):
            term *= c2 * (k - 1) / k
            acc += term
        return s * acc

    lo, hi = 0.0, 1.0
    while central(hi) < level:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if central(mid) < level:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _null_association(reason: str, base: Mapping[str, Any]) -> dict[str, Any]:
    return {
        **base,
        "status": "null",
        "reason": reason,
        "caution": None,
        "slope_g_per_N": None,
        "slope_g_per_100N": None,
        "ci95_g_per_100N": None,
        "ci95_g_per_N": None,
        "ci_method": None,
        "bootstrap": None,
        "sandwich": None,
    }


def association_rows(index: pl.DataFrame, *, stable_only: bool = False) -> pl.DataFrame:
    """Runs that inform the squeeze association: ``ok``, lift succeeded, squeeze reached
    with a recorded removal (``stable_only``: grasp also kept through the squeeze)."""
    reached = reached_mask(index, "squeeze")
    sel = index.filter(
        pl.Series(reached, dtype=pl.Boolean)
        & (pl.col("status") == "ok")
        & pl.col("lift_success").fill_null(False)
        & pl.col("water_removed_squeeze").is_not_null()
    )
    if stable_only:
        sel = sel.filter(pl.col("stable_squeeze").fill_null(False))
    return sel


def squeeze_association(
    index: pl.DataFrame,
    *,
    n_boot: int = DEFAULT_BOOTSTRAP,
    seed: int = 0,
    stable_only: bool = False,
    per_size: bool = True,
) -> dict[str, Any]:
    """Within-group association of squeeze force (N) with the water removed in the squeeze
    phase (reported in g), over ``ok`` runs whose lift succeeded and that reached the squeeze
    (``stable_only``: that also kept the grasp through it).

    Groups are the runs sharing :data:`GROUP_KEYS`; only groups with at least two distinct
    squeeze forces inform the slope. Force and removal are demeaned within each group and
    the slope is ``sum(dx dy) / sum(dx^2)`` (fixed-effects estimator), reported per 100 N.
    Its 95% interval (``ci95_g_per_100N``) is a cluster bootstrap: whole groups are drawn with
    replacement ``n_boot`` times (``numpy.random.default_rng(seed)``) and the 2.5/97.5
    percentiles of the refitted slope are taken. A cluster-robust sandwich interval (CR1:
    factor G/(G-1), Student t with G-1 degrees of freedom) is reported next to it. With
    fewer than two informative groups the result is ``status: "null"`` with a ``reason``.
    """
    sel = association_rows(index, stable_only=stable_only)
    result = _association(sel, n_boot=n_boot, seed=seed)
    result["filter"] = "status ok, lift success, squeeze reached" + (
        ", stable squeeze" if stable_only else ""
    )
    if per_size:
        result["per_size"] = {
            str(size[0]): _association(sub, n_boot=n_boot, seed=seed)
            for size, sub in groups_by(sel, ("size_cm",))
        }
    return result


def _association(sel: pl.DataFrame, *, n_boot: int, seed: int) -> dict[str, Any]:
    groups = groups_by(sel, GROUP_KEYS)
    informative = [g for _, g in groups if g["F_squeeze"].n_unique() >= 2]
    base: dict[str, Any] = {
        "unit": "g per 100 N",
        "group_keys": list(GROUP_KEYS),
        "n_runs": sum(g.height for g in informative),
        "n_groups": len(informative),
        "n_groups_total": len(groups),
        "F_squeeze_values_N": sorted({float(f) for f in sel["F_squeeze"].to_list()}),
    }
    if len(informative) < 2:
        return _null_association(
            f"{len(informative)} group(s) with at least two squeeze forces; need 2", base
        )
    sxx = np.empty(len(informative))
    sxy = np.empty(len(informative))
    parts: list[tuple[np.ndarray, np.ndarray]] = []
    for j, g in enumerate(informative):
        x = g["F_squeeze"].to_numpy().astype(float)
        y = g["water_removed_squeeze"].to_numpy().astype(float) * G_PER_KG
        dx, dy = x - x.mean(), y - y.mean()
        sxx[j], sxy[j] = float(dx @ dx), float(dx @ dy)
        parts.append((dx, dy))
    slope = float(sxy.sum() / sxx.sum())  # g per N
    n_groups = len(informative)

    # Resampling whole groups keeps each group's demeaned sums intact, so a resample's slope
    # is the ratio of summed per-group sums.
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_groups, size=(n_boot, n_groups))
    boot = sxy[draws].sum(axis=1) / sxx[draws].sum(axis=1)
    b_lo, b_hi = np.quantile(boot, [0.025, 0.975])

    scores = np.array([float(dx @ (dy - slope * dx)) for dx, dy in parts])
    var = n_groups / (n_groups - 1) * float(scores @ scores) / float(sxx.sum()) ** 2
    se = math.sqrt(var)
    tc = t_critical(n_groups - 1)
    per100 = 100.0
    return {
        **base,
        "status": "ok",
        "reason": None,
        # Percentile intervals from resampling a handful of clusters are known to be too
        # narrow; say so rather than let a reader take them at face value.
        "caution": None
        if n_groups >= FEW_GROUPS
        else f"only {n_groups} groups: the bootstrap interval is unreliable (too narrow); "
        "the t-based sandwich interval is the more conservative one",
        "slope_g_per_N": slope,
        "slope_g_per_100N": slope * per100,
        "ci95_g_per_100N": [float(b_lo) * per100, float(b_hi) * per100],
        "ci95_g_per_N": [float(b_lo), float(b_hi)],
        "ci_method": f"cluster bootstrap over groups, percentile, {n_boot} resamples, seed {seed}",
        "bootstrap": {
            "n_resamples": n_boot,
            "seed": seed,
            "se_g_per_100N": float(boot.std(ddof=1)) * per100,
            "ci95_g_per_100N": [float(b_lo) * per100, float(b_hi) * per100],
        },
        "sandwich": {
            "method": "cluster-robust (CR1, G/(G-1)), Student t with G-1 df",
            "se_g_per_100N": se * per100,
            "df": n_groups - 1,
            "t_crit": tc,
            "ci95_g_per_100N": [(slope - tc * se) * per100, (slope + tc * se) * per100],
        },
    }
