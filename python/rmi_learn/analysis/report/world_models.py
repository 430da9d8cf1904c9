"""The report's world-model section: Table I (the predictors), Tables II and IV and the
lookahead diagnostic beside the paper's numbers, and the forecast error over the horizon."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rmi_learn.analysis.report.cells import SIZES, fmt, ours_then_paper
from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.figure_files import FIG_SUBDIR, headless_pyplot, save_fig
from rmi_learn.analysis.report.inputs import note_missing, read_json
from rmi_learn.world_models.findings import Finding, paper_findings


def _wm_rows(
    table: dict[str, Any] | None,
    horizon: str,
    metric_names: Sequence[str],
    paper: dict[str, Any],
) -> list[list[str]]:
    rows: list[list[str]] = []
    for r in (table or {}).get("horizons", {}).get(horizon, []):
        cells = [fmt((r.get(f"{s}cm") or {}).get(m)) for s in SIZES for m in metric_names]
        rows += ours_then_paper(r["method"], cells, paper)
    return rows


def section_world_models(doc: Doc, out: Path, figs: Path, paper: dict[str, Any]) -> None:
    """Tables I, II, IV and the lookahead diagnostic, and the horizon figure."""
    doc.h(2, "World models (Tables I, II, IV and the lookahead diagnostic)")
    wm_dir = out / "tables" / "wm"
    results = read_json(wm_dir / "results.json")
    if results is None:
        note_missing(doc, "world-model evaluation", "eval-wm")
        return
    # Table I: the predictors, with our parameter counts and latency.
    roles = {
        "baseline": ("causal", "the latest state through the rollout"),
        "setpoint-readout": ("causal", "the baseline with F_meas read off the setpoints"),
        "state-gru": ("causal", "same GRU as AC-GRU-WM, no command"),
        "ac-gru": ("causal", "proposed world model, one command per step"),
        "transformer": ("causal", "W_T, the scorer of the policy samples"),
        "arx": ("lookahead", "locally linear residual on the full chunk"),
        "ac-mlp": ("lookahead", "one evaluation of (y_t, vec(A_t))"),
    }
    seen: dict[str, dict[str, Any]] = {}
    for r in results:
        if r["state_groups"] == "ALL" and not r["shuffled"]:
            seen.setdefault(r["kind"], r)
    doc.h(3, "Table I: world-model predictors")
    doc.table(
        ["interface", "model", "role", "parameters", "latency 8x32 (ms)"],
        [
            [
                roles[k][0],
                seen[k]["method"],
                roles[k][1],
                f"{seen[k].get('params', 0):,}",
                fmt(seen[k].get("latency_ms_8x32"), 1),
            ]
            for k in roles
            if k in seen
        ],
        "Latency: one rollout of 8 chunks x 32 steps on this CPU (median), the planning load.",
    )
    main = "0.64 s"
    t2 = read_json(wm_dir / "table2.json")
    doc.h(3, "Table II: causal prediction on the test split at 0.64 s")
    doc.table(
        ["method"] + [f"{s} cm {m}" for s in SIZES for m in ("water (g)", "force (N)", "fric.")],
        _wm_rows(t2, main, ("water (g)", "force (N)", "fric."), paper["table2"]),
        "Rows starting with 'paper:' are the paper's numbers. fric. = balanced accuracy over "
        "the four friction classes.",
    )
    _findings(doc, results)
    t4 = read_json(wm_dir / "table4.json")
    doc.h(3, "Table IV: state ablation of AC-GRU-WM (water MAE, g, 0.64 s)")
    doc.table(
        ["state"] + [f"{s} cm" for s in SIZES],
        _wm_rows(t4, main, ("water (g)",), paper["table4"]),
    )
    t3 = read_json(wm_dir / "table3.json")
    doc.h(3, "Lookahead diagnostic: the complete chunk is visible (0.64 s)")
    doc.table(
        ["method"] + [f"{s} cm {m}" for s in SIZES for m in ("water (g)", "force (N)")],
        _wm_rows(t3, main, ("water (g)", "force (N)"), paper["table3_diagnostic"]),
    )
    rel = _horizon_figure(results, figs)
    if rel:
        doc.img(rel, "Forecast water error vs horizon on the test split, per sponge size")


def _finding_cell(f: Finding) -> str:
    def spread(values: tuple[float, ...]) -> str:
        return "" if len(values) < 2 else f" [{min(values):.1f}, {max(values):.1f}]"

    verdict = "holds" if f.holds else "does not hold"
    if len(f.ours_per_seed) > 1 and f.holds and not f.seeds_agree:
        verdict += " (not for every seed)"
    return (
        f"{verdict}: {f.ours:.1f}{spread(f.ours_per_seed)} vs "
        f"{f.other:.1f}{spread(f.other_per_seed)}"
    )


def _findings(doc: Doc, results: list[dict[str, Any]]) -> None:
    """Whether the paper's Table II findings hold on these data, per size, with the range
    over training seeds; one line for each that does not."""
    found = paper_findings(results)
    if not found:
        return
    names = list(dict.fromkeys(f.finding for f in found))
    cells = {(f.finding, f.size_cm): f for f in found}
    doc.h(3, "The paper's Table II findings on these data (water MAE, g, 0.64 s)")
    doc.table(
        ["finding"] + [f"{s} cm" for s in SIZES],
        [
            [n] + [_finding_cell(cells[n, s]) if (n, s) in cells else "–" for s in SIZES]
            for n in names
        ],
        "Mean over the training seeds of each row, the range over seeds in brackets; 'not "
        "for every seed': some seed of the first row is above some seed of the second.",
    )
    for f in found:
        if not f.holds:
            doc.p(
                f"Not on these data: {f.finding} on the {f.size_cm} cm sponge "
                f"({f.ours:.1f} g against {f.other:.1f} g)."
            )


def _horizon_figure(results: list[dict[str, Any]], figs: Path) -> str | None:
    plt = headless_pyplot()
    steps = sorted(
        {
            int(k.split("@")[1])
            for r in results
            for k in r.get("metrics", {})
            if k.startswith("water_mae_g@")
        }
    )
    if not steps:
        return None
    fig, axes = plt.subplots(1, len(SIZES), figsize=(12, 3.6), sharey=False)
    for ax, s in zip(axes, SIZES, strict=True):
        for r in results:
            if r["size_cm"] != s or r["state_groups"] != "ALL":
                continue
            ys = [r["metrics"].get(f"water_mae_g@{k}") for k in steps]
            xs = [k * 0.02 for k, y in zip(steps, ys, strict=True) if y is not None]
            ys = [y for y in ys if y is not None]
            if ys:
                ax.plot(xs, ys, marker="o", ls="--" if r["shuffled"] else "-", label=r["method"])
        ax.set_title(f"{s} cm")
        ax.set_xlabel("horizon (s)")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("water MAE (g)")
    handles, labels = axes[0].get_legend_handles_labels()
    for ax in axes[1:]:
        h, lab = ax.get_legend_handles_labels()
        for hh, ll in zip(h, lab, strict=True):
            if ll not in labels:
                handles.append(hh)
                labels.append(ll)
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.14, 1, 1))
    figs.mkdir(parents=True, exist_ok=True)
    save_fig(fig, figs / "fig_horizon.png")
    plt.close(fig)
    return f"{FIG_SUBDIR}/fig_horizon.png"
