"""Physical analysis of a run grid (paper Sec. VI.A, Figs. 4-6): figures and numbers.

:func:`analyze` reads a sweep directory (``index.parquet`` and ``runs/``) or a bare runs tree,
and writes four PNG figures and ``analysis.json``:

- ``fig4_single_run.png``: one representative run, target/measured gripper force (N) and
  retained water M_L (g) against time (s), controller phases shaded.
- ``fig5_water_per_phase.png``: water removed in each controller phase (g) over every run
  that reached the phase; negative values (water taken back up) are drawn as they are.
- ``fig6_lift_success.png``: lift success rate over porosity x holding force, one panel per
  sponge size, pooled over squeeze forces and seeds; cells without runs are hatched.
- ``fig_squeeze_association.png``: squeeze-phase water removal against squeeze force within
  matched groups (same size, porosity, holding force and seed), with the within-group slope.

Stored data are SI (kg, N, s); grams appear only in figures and JSON. Runs whose status is
``failed`` or ``unstable`` (no usable run file) are counted and left out of every physical
number. The JSON carries the paper's stated numbers next to ours (``paper``); numbers of
runs from the synthetic toy ODE (:mod:`rmi_learn.data.synthetic`) are flagged ``synthetic`` and
mean nothing physically.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from rmi_learn.data.runs import (
    ERROR_FILE,
    PARAM_KEYS,
    RUN_FILE,
    RunFileError,
    atomic_write_bytes,
    atomic_write_json,
    check_run_schema,
    json_safe,
    read_run,
    read_run_meta,
)
from rmi_learn.data.sweep import INDEX_FILE, INDEX_SCHEMA, RUNS_SUBDIR, build_index, index_frame
from rmi_learn.data.synthetic import SOURCE as SYNTHETIC_SOURCE
from rmi_learn.errors import InputError

#: Phases whose water removal is analysed. ``settle`` precedes contact and ``done`` is the
#: release, so neither is a transport phase of the grasp.
ANALYSIS_PHASES: tuple[str, ...] = ("close", "ramp", "hold", "lift", "waiting", "squeeze")
#: Runs sharing these values form one matched group for the squeeze association.
GROUP_KEYS: tuple[str, ...] = ("size_cm", "porosity", "F_hold", "seed")
#: Output file names.
FIGURES: dict[str, str] = {
    "single_run": "fig4_single_run.png",
    "water_per_phase": "fig5_water_per_phase.png",
    "lift_success": "fig6_lift_success.png",
    "squeeze_association": "fig_squeeze_association.png",
}
JSON_FILE = "analysis.json"
G_PER_KG = 1e3
#: Trailing-average window of the retained water in Fig. 4 (s), as in the paper's caption.
TRAILING_WINDOW_S = 2.0
DEFAULT_BOOTSTRAP = 2000
#: Below this many informative groups the association carries a ``caution``.
FEW_GROUPS = 10
_DPI = 130

_PHASE_COLOURS: dict[str, str] = {
    "settle": "#f2f2f2",
    "close": "#dbe9f6",
    "ramp": "#fde0c5",
    "hold": "#fbe3e8",
    "lift": "#d9f0d3",
    "waiting": "#ece2f0",
    "squeeze": "#fff3b0",
    "done": "#e0e0e0",
}
_SIZE_COLOURS: dict[int, str] = {8: "#1b9e77", 10: "#d95f02", 12: "#7570b3"}

#: What the paper states about the physical analysis (Sec. V, Sec. VI.A, Figs. 4-6 and
#: supplement Sec. S4). ``None`` where the paper gives no number.
PAPER: dict[str, Any] = {
    "source": "the rmi paper (manuscript): Secs. V and VI.A, Figs. 4-6, Supp. Sec. S4",
    "counts": {
        "runs_total": 594,
        "stable_squeeze": 410,
        "stable_squeeze_by_size": {"8": 110, "10": 157, "12": 143},
        "lift_success": None,
        "gist": "594 runs over the full grid; 410 complete a stable squeeze after lifting "
        "and form the learning dataset (110 small, 157 medium, 143 large).",
    },
    "single_run": {
        "size_cm": 10,
        "porosity": 0.7,
        "F_hold": 210.0,
        "F_squeeze": 300.0,
        "water_trailing_average_s": 2.0,
        "gist": "Most liquid leaves as the measured force approaches the holding target; "
        "lifting changes retained water only modestly; the later squeeze removes a smaller "
        "additional amount.",
    },
    "water_per_phase": {
        "median_g": None,
        "median_fraction": None,
        "gist": "The initial force ramp and hold dominate transport, lifting has the smallest "
        "median effect, and the later squeeze removes part of the remaining liquid.",
    },
    "lift_success": {
        "rate_at_porosity_0.5": 1.0,
        "rate_range_at_porosity_0.7": [0.20, 0.64],
        "most_robust_sizes_cm_at_porosity_0.7": [10],
        "min_F_hold_with_success": None,
        "gist": "Every sponge lifts at porosity 0.5; at 0.7 success ranges from 20% to 64%, "
        "the medium sponge being the most robust; higher porosity needs a stronger holding "
        "force. Each cell pools the six squeeze forces.",
    },
    "squeeze_association": {
        "slope_g_per_N": 0.669,
        "ci95_g_per_N": [0.610, 0.728],
        "slope_g_per_100N": 66.9,
        "ci95_g_per_100N": [61.0, 72.8],
        "group_keys": ["size_cm", "porosity", "F_hold"],
        "ci_method": "clustered 95% confidence interval (method not stated)",
        "per_size": None,
        "gist": "Within groups matched by size, porosity and holding force, each additional "
        "newton of squeeze force is associated with 0.669 g more water removed (clustered "
        "95% CI 0.610-0.728 g); an association, not an isolated causal force sweep.",
    },
}


class AnalysisError(InputError, ValueError):
    """The input directory cannot be analysed (missing, empty, unreadable, unknown run)."""


@dataclass
class RunTable:
    """One row per run with the columns of :func:`rmi_learn.data.sweep.build_index`, plus
    ``reached_<phase>`` (bool, null without a run file) for :data:`ANALYSIS_PHASES` and
    ``source`` (the run config's ``source`` or null)."""

    index: pl.DataFrame
    #: Directory the index's ``path`` column is relative to.
    base: Path
    #: ``index.parquet``, ``sweep tree`` or ``bare runs tree``.
    origin: str


# --------------------------------------------------------------------------------------
# Loading


def _normalise_index(df: pl.DataFrame | None) -> pl.DataFrame:
    """Give an index every column the analysis reads, with fixed types (a grid where, say,
    no run failed has an all-null ``failure`` column of unknown type)."""
    types = INDEX_SCHEMA
    if df is None:
        df = pl.DataFrame(schema=types)
    df = df.with_columns(
        [
            pl.col(c).cast(t, strict=False) if c in df.columns else pl.lit(None, t).alias(c)
            for c, t in types.items()
        ]
    )
    return df.sort("run_id") if df.height else df


def _run_facts(path: Path) -> tuple[set[str] | None, str | None]:
    """Phases a run file visits and its config ``source`` (``None`` if unreadable). Raises
    :class:`RunFileError` for a readable file whose columns break the run-file contract."""
    try:
        schema = pl.read_parquet_schema(path)
    except (OSError, pl.exceptions.PolarsError):
        return None, None
    check_run_schema(path, schema)
    try:
        phases = pl.read_parquet(path, columns=["phase"])["phase"].unique().to_list()
        source = read_run_meta(path)["config"].get("source")
    except (OSError, RunFileError, pl.exceptions.PolarsError):
        return None, None
    return {str(p) for p in phases}, None if source is None else str(source)


def load_runs(runs_dir: str | os.PathLike[str]) -> RunTable:
    """Read the runs of ``runs_dir``: its ``index.parquet`` if present, else the index
    rebuilt from ``runs_dir/runs`` (a sweep directory) or from ``runs_dir`` itself (a bare
    runs tree), without the runs that followed perturbed force targets. The engine records
    0 kg for phases a run never reached, so which phases a run visited is read from each run
    file's ``phase`` column.

    Raises :class:`AnalysisError` when the directory is missing, holds no run or cannot be
    read."""
    root = Path(runs_dir)
    if not root.exists():
        raise AnalysisError(f"{root} does not exist")
    if not root.is_dir():
        raise AnalysisError(f"{root} is not a directory")
    try:
        if (root / INDEX_FILE).is_file():
            index, origin = _normalise_index(pl.read_parquet(root / INDEX_FILE)), INDEX_FILE
        elif (root / RUNS_SUBDIR).is_dir():
            index, origin = _normalise_index(build_index(root, write=False)), "sweep tree"
        else:
            index, origin = _normalise_index(index_frame(root, root)), "bare runs tree"
    except (OSError, KeyError, ValueError, pl.exceptions.PolarsError) as exc:
        raise AnalysisError(f"cannot read the runs of {root}: {exc}") from exc
    if index.height == 0:
        raise AnalysisError(
            f"{root} holds no runs (expected {INDEX_FILE}, {RUNS_SUBDIR}/ or a tree of "
            f"{RUN_FILE} / {ERROR_FILE} files)"
        )
    # The tables relate water removed to the scripted squeeze force; runs that followed
    # perturbed force targets from the lift on (data for the world models) have none.
    index = index.filter(~pl.col("perturbed").fill_null(False))
    if index.height == 0:
        raise AnalysisError(f"{root} holds only runs with perturbed force targets")
    reached: dict[str, list[bool | None]] = {ph: [] for ph in ANALYSIS_PHASES}
    sources: list[str | None] = []
    for rel, status in zip(index["path"].to_list(), index["status"].to_list(), strict=True):
        phases: set[str] | None = None
        source: str | None = None
        if status == "ok" and rel is not None and str(rel).endswith(RUN_FILE):
            phases, source = _run_facts(root / str(rel))
        for ph in ANALYSIS_PHASES:
            reached[ph].append(None if phases is None else ph in phases)
        sources.append(source)
    index = index.with_columns(
        [pl.Series(f"reached_{ph}", v, dtype=pl.Boolean) for ph, v in reached.items()]
        + [pl.Series("source", sources, dtype=pl.String)]
    )
    return RunTable(index=index, base=root, origin=origin)


# --------------------------------------------------------------------------------------
# Numbers


def _ok(index: pl.DataFrame) -> pl.DataFrame:
    return index.filter(pl.col("status") == "ok")


def _reached_mask(index: pl.DataFrame, phase: str) -> np.ndarray:
    """Rows that reached ``phase``: from the run file where known, else a recorded value."""
    has_value = index[f"water_removed_{phase}"].is_not_null().to_numpy()
    col = f"reached_{phase}"
    if col not in index.columns:
        return np.asarray(has_value, dtype=bool)
    known = index[col].to_list()
    return np.array(
        [
            bool(v) and bool(k) if k is not None else bool(v)
            for v, k in zip(has_value, known, strict=True)
        ],
        dtype=bool,
    )


def _bool_count(series: pl.Series) -> int:
    return int(series.fill_null(False).sum())


def run_counts(index: pl.DataFrame) -> dict[str, Any]:
    """Runs in total and by status, and among ``ok`` runs the lift successes and stable
    squeezes, overall and per sponge size."""
    status = index["status"].to_list()
    ok = _ok(index)
    by_size: dict[str, dict[str, int]] = {}
    for size in sorted({int(s) for s in index["size_cm"].to_list()}):
        sub = index.filter(pl.col("size_cm") == size)
        oks = _ok(sub)
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


def _median_of_values(values: Sequence[float]) -> float:
    return float(np.median(np.unique(np.asarray(values, dtype=float))))


def choose_representative(
    table: RunTable, run_id: str | None = None
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The run plotted in Fig. 4 and why: ``run_id`` if given, else the ``ok`` run with lift
    success and a stable squeeze whose parameters (size, porosity, holding and squeeze
    force, each scaled by its range over the grid) lie closest to the median of the grid's
    distinct values; ties go to the smaller seed, then the run id. Raises
    :class:`AnalysisError` for an unknown ``run_id`` or one without a run file."""
    idx = table.index
    if run_id is not None:
        rows = idx.filter(pl.col("run_id") == run_id).to_dicts()
        if not rows:
            raise AnalysisError(f"no run {run_id!r} in {table.base}")
        row = rows[0]
        if row["status"] != "ok" or not str(row["path"]).endswith(RUN_FILE):
            raise AnalysisError(f"run {run_id!r} has no run file (status {row['status']})")
        return row, {"rule": "chosen with --run-id"}
    ok = _ok(idx)
    keys = ("size_cm", "porosity", "F_hold", "F_squeeze")
    target = {k: _median_of_values(ok[k].to_list()) for k in keys} if ok.height else {}
    cand = ok.filter(
        pl.col("lift_success").fill_null(False) & pl.col("stable_squeeze").fill_null(False)
    )
    if cand.height == 0:
        return {}, {"rule": "none: no run with lift success and a stable squeeze"}
    dist = np.zeros(cand.height)
    for k in keys:
        vals = ok[k].to_numpy().astype(float)
        span = float(vals.max() - vals.min())
        if span > 0:
            dist += ((cand[k].to_numpy().astype(float) - target[k]) / span) ** 2
    order = sorted(
        range(cand.height),
        key=lambda i: (round(float(dist[i]), 12), cand["seed"][i], cand["run_id"][i]),
    )
    row = cand.row(order[0], named=True)
    return row, {
        "rule": "lift success and stable squeeze, closest to the grid's median parameters "
        "(each scaled by its range)",
        "grid_median": target,
        "distance": float(math.sqrt(dist[order[0]])),
    }


def water_per_phase(index: pl.DataFrame) -> dict[str, Any]:
    """Water removed in each phase of :data:`ANALYSIS_PHASES` (g) over the ``ok`` runs that
    reached it: count, median, quartiles, extremes and how many are negative (water taken
    back up or counted back). ``median_fraction`` is the median over runs that reached
    every phase of each phase's share of their summed removal (runs whose sum is not
    positive are left out); medians of shares need not sum to 1. ``pooled_fraction`` is the
    phase's share of the summed removal of those runs, which does sum to 1."""
    ok = _ok(index)
    per_phase: dict[str, Any] = {}
    values: dict[str, np.ndarray] = {}
    reached_all = np.ones(ok.height, dtype=bool)
    for ph in ANALYSIS_PHASES:
        mask = _reached_mask(ok, ph)
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
    ok = _ok(index).filter(pl.col("lift_success").is_not_null())
    sizes = sorted({int(s) for s in ok["size_cm"].to_list()})
    porosities = sorted({float(p) for p in ok["porosity"].to_list()})
    holds = sorted({float(f) for f in ok["F_hold"].to_list()})
    cells: list[dict[str, Any]] = []
    by_sp: list[dict[str, Any]] = []
    for (size, por, hold), sub in _groups(ok, ("size_cm", "porosity", "F_hold")):
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


def _groups(df: pl.DataFrame, keys: Sequence[str]) -> list[tuple[tuple[Any, ...], pl.DataFrame]]:
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
    reached = _reached_mask(index, "squeeze")
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
            for size, sub in _groups(sel, ("size_cm",))
        }
    return result


def _association(sel: pl.DataFrame, *, n_boot: int, seed: int) -> dict[str, Any]:
    groups = _groups(sel, GROUP_KEYS)
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


# --------------------------------------------------------------------------------------
# Figures


def _save(fig: Figure, path: Path) -> Path:
    """Render ``fig`` to PNG in memory and write it atomically (no half-written file)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI)
    data = buf.getvalue()
    return atomic_write_bytes(path, lambda f: f.write(data))


def _message(fig: Figure, text: str) -> None:
    fig.text(0.5, 0.5, text, ha="center", va="center", wrap=True)


def _trailing_mean(t: np.ndarray, y: np.ndarray, window: float) -> np.ndarray:
    """Mean of ``y`` over the samples in (t - window, t] at each time ``t`` (s)."""
    cs = np.concatenate([[0.0], np.cumsum(y)])
    start = np.searchsorted(t, t - window, side="right")
    stop = np.arange(1, t.size + 1)
    return np.asarray((cs[stop] - cs[start]) / (stop - start))


def _phase_segments(t: np.ndarray, phase: Sequence[str]) -> list[tuple[str, float, float]]:
    segs: list[tuple[str, float, float]] = []
    start = 0
    for i in range(1, len(phase) + 1):
        if i == len(phase) or phase[i] != phase[start]:
            end = float(t[i]) if i < len(phase) else float(t[-1])
            segs.append((phase[start], float(t[start]), end))
            start = i
    return segs


def plot_single_run(df: pl.DataFrame, title: str) -> Figure:
    """Fig. 4 analogue of one run's rows (see :func:`rmi_learn.data.runs.read_run`): F_target,
    F_meas and lightly F_L/F_R (N) on the left axis, retained water M_L and its trailing
    average (g) on the right, phases shaded and named."""
    fig = Figure(figsize=(9.0, 4.8), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    t = df["time"].to_numpy()
    phase = [str(p) for p in df["phase"].to_list()]
    for name, t0, t1 in _phase_segments(t, phase):
        ax.axvspan(t0, t1, color=_PHASE_COLOURS.get(name, "#eeeeee"), lw=0, zorder=0)
        ax.text(
            0.5 * (t0 + t1),
            1.01,
            name,
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=7,
            rotation=45 if t1 - t0 < 0.08 * (t[-1] - t[0]) else 0,
        )
    ax.plot(t, df["F_L"].to_numpy(), color="tab:blue", lw=0.6, alpha=0.35, label="F_L")
    ax.plot(t, df["F_R"].to_numpy(), color="tab:cyan", lw=0.6, alpha=0.35, label="F_R")
    ax.plot(t, df["F_target"].to_numpy(), color="black", ls="--", lw=1.2, label="F_target")
    ax.plot(t, df["F_meas"].to_numpy(), color="tab:blue", lw=1.4, label="F_meas")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("gripper force (N)")
    ax.set_xlim(float(t[0]), float(t[-1]))
    ax2 = ax.twinx()
    m = df["M_L"].to_numpy() * G_PER_KG
    ax2.plot(t, m, color="darkred", lw=1.5, label="M_L")
    ax2.plot(
        t,
        _trailing_mean(t, m, TRAILING_WINDOW_S),
        color="tab:red",
        lw=1.0,
        ls="--",
        alpha=0.7,
        label=f"M_L, {TRAILING_WINDOW_S:g} s trailing mean (as in the paper)",
    )
    ax2.set_ylabel("retained water M_L (g)")
    lines = ax.get_lines() + ax2.get_lines()
    fig.legend(
        lines, [str(x.get_label()) for x in lines], loc="outside lower center", ncol=3, fontsize=7
    )
    fig.suptitle(title, fontsize=9)
    return fig


def plot_water_per_phase(
    values_g: Mapping[str, np.ndarray], sizes: Mapping[str, np.ndarray], title: str
) -> Figure:
    """Fig. 5 analogue: one box per phase of the water removed (g), every run drawn as a
    point coloured by sponge size; the zero line shows where water was taken back up."""
    fig = Figure(figsize=(8.0, 4.6), layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    phases = list(ANALYSIS_PHASES)
    present = [i for i, ph in enumerate(phases) if values_g[ph].size]
    if present:
        ax.boxplot(
            [values_g[phases[i]] for i in present],
            positions=[i + 1 for i in present],
            widths=0.55,
            showfliers=False,
            medianprops={"color": "black"},
        )
    rng = np.random.default_rng(0)
    seen: set[int] = set()
    for i, ph in enumerate(phases):
        v = values_g[ph]
        s = sizes[ph]
        for size in sorted({int(x) for x in s}):
            pick = s == size
            ax.scatter(
                i + 1 + rng.uniform(-0.18, 0.18, int(pick.sum())),
                v[pick],
                s=9,
                alpha=0.6,
                color=_SIZE_COLOURS.get(size, "grey"),
                label=f"{size} cm" if size not in seen else None,
                zorder=3,
            )
            seen.add(size)
        ax.text(
            i + 1,
            1.0,
            f"n={v.size}",
            transform=ax.get_xaxis_transform(),
            ha="center",
            va="bottom",
            fontsize=7,
        )
    ax.axhline(0.0, color="grey", lw=0.8, ls=":")
    ax.set_xticks(range(1, len(phases) + 1), phases)
    ax.set_xlim(0.4, len(phases) + 0.6)
    ax.set_ylabel("water removed in phase (g)")
    if seen:
        ax.legend(fontsize=7, title="sponge", title_fontsize=7)
    fig.suptitle(title, fontsize=9)
    return fig


def plot_lift_success(table: Mapping[str, Any], title: str) -> Figure:
    """Fig. 6 analogue: lift success rate per porosity (rows) x holding force (columns),
    one panel per sponge size; hatched cells had no run."""
    sizes: list[int] = list(table["sizes_cm"])
    pors: list[float] = list(table["porosities"])
    holds: list[float] = list(table["F_hold_values"])
    fig = Figure(figsize=(4.2 * max(1, len(sizes)) + 0.8, 3.8), layout="constrained")
    if not sizes:
        _message(fig, "no run with a lift outcome")
        return fig
    axes = [fig.add_subplot(1, len(sizes), i + 1) for i in range(len(sizes))]
    image = None
    for ax, size in zip(axes, sizes, strict=True):
        rate = np.full((len(pors), len(holds)), np.nan)
        label = [["" for _ in holds] for _ in pors]
        for c in table["cells"]:
            if c["size_cm"] != size:
                continue
            i, j = pors.index(c["porosity"]), holds.index(c["F_hold"])
            rate[i, j] = c["rate"]
            label[i][j] = f"{c['rate']:.0%}\n{c['n_success']}/{c['n']}"
        image = ax.imshow(
            np.ma.masked_invalid(rate),
            origin="lower",
            aspect="auto",
            cmap="RdYlGn",
            vmin=0.0,
            vmax=1.0,
            extent=(-0.5, len(holds) - 0.5, -0.5, len(pors) - 0.5),
        )
        for i in range(len(pors)):
            for j in range(len(holds)):
                if np.isnan(rate[i, j]):
                    ax.add_patch(_missing_cell(j, i))
                    ax.text(j, i, "no runs", ha="center", va="center", fontsize=6)
                else:
                    ax.text(
                        j,
                        i,
                        label[i][j],
                        ha="center",
                        va="center",
                        fontsize=7,
                        bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 1.5},
                    )
        ax.set_xticks(range(len(holds)), [f"{h:g}" for h in holds])
        ax.set_yticks(range(len(pors)), [f"{p:g}" for p in pors])
        ax.set_xlabel("holding force F_hold (N)")
        ax.set_ylabel("porosity")
        ax.set_title(f"{size} cm sponge", fontsize=9)
    if image is not None:
        fig.colorbar(image, ax=axes, label="lift success rate", shrink=0.85)
    fig.suptitle(title, fontsize=9)
    return fig


def _missing_cell(x: int, y: int) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle(
        (x - 0.5, y - 0.5), 1.0, 1.0, facecolor="#dddddd", hatch="//", edgecolor="grey", lw=0.0
    )


def plot_association(sel: pl.DataFrame, assoc: Mapping[str, Any], title: str) -> Figure:
    """Squeeze association figure: left, squeeze-phase removal (g) against squeeze force (N),
    one line per matched group coloured by size; right, both demeaned within group, with
    the fitted slope and its bootstrap interval."""
    fig = Figure(figsize=(10.0, 4.4), layout="constrained")
    ax1 = fig.add_subplot(1, 2, 1)
    ax2 = fig.add_subplot(1, 2, 2)
    labelled: set[int] = set()
    for key, g in _groups(sel, GROUP_KEYS):
        size = int(key[0])
        g = g.sort("F_squeeze")
        x = g["F_squeeze"].to_numpy().astype(float)
        y = g["water_removed_squeeze"].to_numpy().astype(float) * G_PER_KG
        col = _SIZE_COLOURS.get(size, "grey")
        lab = f"{size} cm" if size not in labelled else None
        labelled.add(size)
        ax1.plot(x, y, marker="o", ms=3, lw=0.8, alpha=0.7, color=col, label=lab)
        if g["F_squeeze"].n_unique() >= 2:
            ax2.scatter(x - x.mean(), y - y.mean(), s=10, alpha=0.7, color=col)
    ax1.set_xlabel("squeeze force F_squeeze (N)")
    ax1.set_ylabel("water removed in squeeze phase (g)")
    ax1.set_title("matched groups (size, porosity, F_hold, seed)", fontsize=8)
    if labelled:
        ax1.legend(fontsize=7)
    ax2.axhline(0.0, color="grey", lw=0.6, ls=":")
    ax2.set_xlabel("squeeze force minus group mean (N)")
    ax2.set_ylabel("removal minus group mean (g)")
    if assoc.get("status") == "ok":
        xs = np.asarray(ax2.get_xlim())
        b = float(assoc["slope_g_per_N"])
        lo, hi = (v / 100.0 for v in assoc["ci95_g_per_100N"])
        ax2.plot(xs, b * xs, color="black", lw=1.4, label=f"{100 * b:.2f} g / 100 N")
        ax2.fill_between(xs, lo * xs, hi * xs, color="black", alpha=0.12, label="95% CI")
        ax2.set_xlim(*xs)
        ax2.legend(fontsize=7)
        ax2.set_title(
            f"within-group slope, {assoc['n_groups']} groups, cluster bootstrap CI", fontsize=8
        )
    else:
        ax2.text(
            0.5,
            0.5,
            f"no estimate: {assoc.get('reason')}",
            transform=ax2.transAxes,
            ha="center",
            va="center",
            fontsize=8,
            wrap=True,
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
        )
    fig.suptitle(title, fontsize=9)
    return fig


# --------------------------------------------------------------------------------------
# Driver


def _ours_vs_paper(counts: Mapping[str, Any], lift: Mapping[str, Any]) -> dict[str, Any]:
    """Our figures for the quantities the paper states, in the paper's terms."""

    def rates_at(por: float) -> dict[str, float]:
        return {
            str(r["size_cm"]): r["rate"]
            for r in lift["by_size_porosity"]
            if math.isclose(r["porosity"], por)
        }

    at5, at7 = rates_at(0.5), rates_at(0.7)
    return {
        "runs_total": counts["runs_total"],
        "stable_squeeze": counts["lift_and_stable_squeeze"],
        "lift_rate_at_porosity_0.5": at5 or None,
        "lift_rate_range_at_porosity_0.7": [min(at7.values()), max(at7.values())] if at7 else None,
        "most_robust_sizes_cm_at_porosity_0.7": sorted(
            int(k) for k, v in at7.items() if v == max(at7.values())
        )
        if at7
        else None,
    }


def analyze(
    runs_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    run_id: str | None = None,
    *,
    n_boot: int = DEFAULT_BOOTSTRAP,
    seed: int = 0,
) -> dict[str, Any]:
    """Analyse the runs of ``runs_dir`` (see :func:`load_runs`) and write the four figures
    of :data:`FIGURES` and ``analysis.json`` to ``out_dir``, every file atomically. Returns
    the JSON content. ``run_id`` picks the run of Fig. 4 (default: see
    :func:`choose_representative`); ``n_boot`` and ``seed`` set the cluster bootstrap.
    Raises :class:`AnalysisError` for unusable input."""
    table = load_runs(runs_dir)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    index = table.index
    sources = sorted({s for s in index["source"].to_list() if s is not None})
    synthetic = SYNTHETIC_SOURCE in sources
    tag = " [SYNTHETIC TOY DATA: not physics]" if synthetic else ""
    counts = run_counts(index)

    # Fig. 4
    row, why = choose_representative(table, run_id)
    single: dict[str, Any] | None = None
    if row:
        frame, _ = read_run(table.base / str(row["path"]))
        params = {k: row[k] for k in PARAM_KEYS}
        fig = plot_single_run(
            frame,
            f"{row['run_id']}: lift {'ok' if row['lift_success'] else 'failed'}, "
            f"squeeze {'stable' if row['stable_squeeze'] else 'not stable'}{tag}",
        )
        single = {
            "run_id": row["run_id"],
            "params": params,
            "lift_success": row["lift_success"],
            "stable_squeeze": row["stable_squeeze"],
            "failure": row["failure"],
            "initial_water_g": _g(row["initial_water"]),
            "final_water_g": _g(row["final_water"]),
            "water_removed_g": {ph: _g(row[f"water_removed_{ph}"]) for ph in ANALYSIS_PHASES},
            "selection": why,
        }
    else:
        fig = Figure(figsize=(9.0, 4.8), layout="constrained")
        _message(fig, f"no run to plot: {why['rule']}")
    _save(fig, out / FIGURES["single_run"])

    # Fig. 5
    water = water_per_phase(index)
    values_g = water.pop("_values_g")  # for the figure only, not the JSON
    ok = _ok(index)
    sizes_by_phase = {ph: ok["size_cm"].to_numpy()[_reached_mask(ok, ph)] for ph in ANALYSIS_PHASES}
    _save(
        plot_water_per_phase(values_g, sizes_by_phase, f"Water removed per controller phase{tag}"),
        out / FIGURES["water_per_phase"],
    )

    # Fig. 6
    lift = lift_success_table(index)
    _save(
        plot_lift_success(lift, f"Lift success over porosity and holding force{tag}"),
        out / FIGURES["lift_success"],
    )

    # Squeeze association
    assoc = squeeze_association(index, n_boot=n_boot, seed=seed)
    stable = squeeze_association(index, n_boot=n_boot, seed=seed, stable_only=True, per_size=False)
    _save(
        plot_association(
            association_rows(index), assoc, f"Squeeze force and squeeze-phase water removal{tag}"
        ),
        out / FIGURES["squeeze_association"],
    )

    result: dict[str, Any] = {
        "input": {"runs_dir": str(Path(runs_dir)), "read_from": table.origin},
        "synthetic": synthetic,
        "run_sources": sources,
        "note": (
            "synthetic toy-ODE runs: these numbers test the code and mean nothing physically"
            if synthetic
            else None
        ),
        "counts": counts,
        "single_run": single,
        "single_run_reason": None if single else why["rule"],
        "water_per_phase": water,
        "water_removed_median_g": {ph: water["per_phase"][ph]["median"] for ph in ANALYSIS_PHASES},
        "lift_success": lift,
        "squeeze_association": assoc,
        "squeeze_association_stable_only": stable,
        "ours_in_paper_terms": _ours_vs_paper(counts, lift),
        "paper": PAPER,
        "files": dict(FIGURES, json=JSON_FILE),
    }
    clean = json_safe(result)
    clean["summary_text"] = " ".join(summary_lines(clean))
    atomic_write_json(out / JSON_FILE, clean)
    return dict(clean)


def _g(kg: Any) -> float | None:
    return None if kg is None else float(kg) * G_PER_KG


def summary_lines(result: Mapping[str, Any]) -> list[str]:
    """A few lines of text summarising :func:`analyze`'s result for the terminal."""
    c = result["counts"]
    lines = [
        f"{c['runs_total']} runs: {c['ok']} ok, {c['failed']} failed, {c['unstable']} "
        f"unstable; {c['lift_success']} lift successes, {c['stable_squeeze']} stable squeezes"
    ]
    single = result.get("single_run")
    lines.append(
        f"Fig. 4 run: {single['run_id']}" if single else f"Fig. 4: {result['single_run_reason']}"
    )
    med = result["water_per_phase"]["per_phase"]
    lines.append(
        "median water removed (g): "
        + ", ".join(
            f"{ph} {med[ph]['median']:.2f}" if med[ph]["median"] is not None else f"{ph} n/a"
            for ph in ANALYSIS_PHASES
        )
    )
    a = result["squeeze_association"]
    if a["status"] == "ok":
        lo, hi = a["ci95_g_per_100N"]
        lines.append(
            f"squeeze association: {a['slope_g_per_100N']:.2f} g per 100 N "
            f"(95% CI {lo:.2f} to {hi:.2f}, cluster bootstrap, {a['n_groups']} groups)"
        )
    else:
        lines.append(f"squeeze association: none ({a['reason']})")
    if result.get("synthetic"):
        lines.append("NOTE: synthetic toy-ODE runs; the numbers mean nothing physically")
    return lines
