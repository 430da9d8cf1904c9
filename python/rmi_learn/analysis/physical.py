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

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl

from rmi_learn.analysis.figures import (
    no_run_figure,
    plot_association,
    plot_lift_success,
    plot_single_run,
    plot_water_per_phase,
    save_png,
)
from rmi_learn.analysis.paper import physical_claims
from rmi_learn.analysis.run_table import (
    ANALYSIS_PHASES,
    RunTable,
    choose_representative,
    load_runs,
    ok_runs,
    reached_mask,
)
from rmi_learn.analysis.statistics import (
    DEFAULT_BOOTSTRAP,
    G_PER_KG,
    association_rows,
    lift_success_table,
    run_counts,
    squeeze_association,
    water_per_phase,
)
from rmi_learn.data.runs import PARAM_KEYS, atomic_write_json, json_safe, read_run
from rmi_learn.data.synthetic import SOURCE as SYNTHETIC_SOURCE

#: Output file names.
FIGURES: dict[str, str] = {
    "single_run": "fig4_single_run.png",
    "water_per_phase": "fig5_water_per_phase.png",
    "lift_success": "fig6_lift_success.png",
    "squeeze_association": "fig_squeeze_association.png",
}
JSON_FILE = "analysis.json"


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


@dataclass(frozen=True)
class Representative:
    """The run of Fig. 4 (``row`` and its ``frame``; both ``None`` without one) and why it
    was chosen (``why``)."""

    row: dict[str, Any] | None
    why: dict[str, Any]
    frame: pl.DataFrame | None


def _representative(table: RunTable, run_id: str | None) -> Representative:
    """Fig. 4's run, its run file read (and so checked) before anything is written."""
    row, why = choose_representative(table, run_id)
    frame = read_run(table.base / str(row["path"]))[0] if row else None
    return Representative(row, why, frame)


def _single_run(
    chosen: Representative, tag: str, path: Path
) -> tuple[dict[str, Any] | None, dict[str, Any]]:
    """Fig. 4: draw the representative run (or say why there is none) into ``path``;
    returns the run's JSON entry (``None`` without a run) and why it was chosen."""
    row, why = chosen.row, chosen.why
    single: dict[str, Any] | None = None
    if row and chosen.frame is not None:
        params = {k: row[k] for k in PARAM_KEYS}
        fig = plot_single_run(
            chosen.frame,
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
        fig = no_run_figure(f"no run to plot: {why['rule']}")
    save_png(fig, path)
    return single, why


def _water_removed(index: pl.DataFrame, tag: str, path: Path) -> dict[str, Any]:
    """Fig. 5: the water removed per phase, drawn into ``path``; returns its numbers."""
    water = water_per_phase(index)
    values_g = water.pop("_values_g")  # for the figure only, not the JSON
    ok = ok_runs(index)
    sizes_by_phase = {ph: ok["size_cm"].to_numpy()[reached_mask(ok, ph)] for ph in ANALYSIS_PHASES}
    save_png(
        plot_water_per_phase(values_g, sizes_by_phase, f"Water removed per controller phase{tag}"),
        path,
    )
    return water


def _lift_success(index: pl.DataFrame, tag: str, path: Path) -> dict[str, Any]:
    """Fig. 6: the lift success table, drawn into ``path``; returns it."""
    lift = lift_success_table(index)
    save_png(plot_lift_success(lift, f"Lift success over porosity and holding force{tag}"), path)
    return lift


def _association(
    index: pl.DataFrame, n_boot: int, seed: int, tag: str, path: Path
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The squeeze association over every informative run and over stable squeezes only,
    the first drawn into ``path``."""
    assoc = squeeze_association(index, n_boot=n_boot, seed=seed)
    stable = squeeze_association(index, n_boot=n_boot, seed=seed, stable_only=True, per_size=False)
    save_png(
        plot_association(
            association_rows(index), assoc, f"Squeeze force and squeeze-phase water removal{tag}"
        ),
        path,
    )
    return assoc, stable


def analyze(
    runs_dir: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    run_id: str | None = None,
    *,
    n_boot: int = DEFAULT_BOOTSTRAP,
    seed: int = 0,
) -> dict[str, Any]:
    """Analyse the runs of ``runs_dir`` (see :func:`~rmi_learn.analysis.run_table.load_runs`)
    and write the four figures of :data:`FIGURES` and ``analysis.json`` to ``out_dir``, every
    file atomically. Returns the JSON content. ``run_id`` picks the run of Fig. 4 (default:
    see :func:`~rmi_learn.analysis.run_table.choose_representative`); ``n_boot`` and ``seed``
    set the cluster bootstrap. Raises :class:`~rmi_learn.analysis.run_table.AnalysisError`
    for unusable input and :class:`~rmi_learn.errors.RunFileError` for a damaged run file of
    Fig. 4, both before ``out_dir`` is created."""
    table = load_runs(runs_dir)
    chosen = _representative(table, run_id)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return _write_analysis(table, chosen, Path(runs_dir), out, n_boot, seed)


def _write_analysis(
    table: RunTable, chosen: Representative, runs_dir: Path, out: Path, n_boot: int, seed: int
) -> dict[str, Any]:
    """Draw the figures and write ``analysis.json`` into ``out``; returns the JSON content."""
    index = table.index
    sources = sorted({s for s in index["source"].to_list() if s is not None})
    synthetic = SYNTHETIC_SOURCE in sources
    tag = " [SYNTHETIC TOY DATA: not physics]" if synthetic else ""
    counts = run_counts(index)
    single, why = _single_run(chosen, tag, out / FIGURES["single_run"])
    water = _water_removed(index, tag, out / FIGURES["water_per_phase"])
    lift = _lift_success(index, tag, out / FIGURES["lift_success"])
    assoc, stable = _association(index, n_boot, seed, tag, out / FIGURES["squeeze_association"])
    result: dict[str, Any] = {
        "input": {"runs_dir": str(runs_dir), "read_from": table.origin},
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
        "paper": physical_claims(),
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
