"""The report's policy section: Tables III, V and S1 beside the paper's numbers, and the
terminal water error as the scorer predicts it and as the simulator realises it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rmi_learn.analysis.report.cells import SIZES, fmt, ours_then_paper
from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.figure_files import FIG_SUBDIR, headless_pyplot, save_fig
from rmi_learn.analysis.report.inputs import note_missing, read_json


def _rank_rows(table: dict[str, Any] | None, paper: dict[str, Any]) -> list[list[str]]:
    rows: list[list[str]] = []
    for r in (table or {}).get("rows", []):
        rows += ours_then_paper(r["method"], [fmt(r.get(str(s))) for s in SIZES], paper)
    return rows


def section_policies(doc: Doc, out: Path, figs: Path, paper: dict[str, Any]) -> None:
    """Tables III, V and S1 and the ranking figure."""
    doc.h(2, "Policies and ranking (Tables III, V, S1)")
    rank = out / "tables" / "rank"
    t3 = read_json(rank / "table3_ranking.json")
    if t3 is None:
        note_missing(doc, "ranking tables", "rank")
        return
    nw = t3.get("n_windows", {})
    doc.p(
        f"{t3.get('split', 'test')} windows per size: "
        + ", ".join(f"{s} cm {nw.get(str(s), 0)}" for s in SIZES)
        + f"; K = {t3.get('k', 8)} samples per window."
    )
    # Rankings written before the scorer was named in them were all W_T's.
    scorer = str(t3.get("scorer_name", "W_T"))
    doc.h(3, f"Table III: {scorer}-predicted terminal water error (g)")
    doc.table(
        ["method"] + [f"{s} cm" for s in SIZES],
        _rank_rows(t3, paper["table3_ranking"]),
        "Predicted by the scorer that selects the chunk, so biased toward it; the closed-loop "
        "section executes the chunks in the simulator.",
    )
    _ranking_findings(doc, t3, read_json(out / "closed_loop" / "table_closed_loop.json"), scorer)
    t5 = read_json(rank / "table5_imitation.json")
    doc.h(3, "Table V: force MAE and smoothness of one sample (N)")
    rows = []
    for r in (t5 or {}).get("rows", []):
        cells = []
        for s in SIZES:
            v = r.get(str(s)) or {}
            # The reference row has MAE 0 by definition; show it only where data exist.
            has = v.get("smooth_F") is not None
            cells += [fmt(v.get(q)) if has else "–" for q in ("MAE_F", "smooth_F")]
        rows += ours_then_paper(r["method"], cells, paper["table5"])
    doc.table(["method"] + [f"{s} cm {q}" for s in SIZES for q in ("MAE_F", "smooth_F")], rows)
    tS1 = read_json(rank / "tableS1_cost.json")
    doc.h(3, "Table S1: combined predicted cost J")
    doc.table(["action source"] + [f"{s} cm" for s in SIZES], _rank_rows(tS1, paper["tableS1"]))
    cl = read_json(out / "closed_loop" / "table_closed_loop.json")
    rel = _ranking_figure(t3, cl, figs, scorer)
    if rel:
        doc.img(
            rel,
            f"Terminal water error per size and action source: as {scorer} predicts it (left) and "
            "as the simulator realises it (right, closed loop)",
        )


def _ranking_findings(doc: Doc, t3: dict[str, Any], cl: dict[str, Any] | None, scorer: str) -> None:
    """The paper's ranking claim per policy and size: the selected chunk's predicted error
    at most half the first sample's, and beside it what the simulator gives both; the rows
    of Table III that ``scorer`` selected."""
    predicted = {r["method"]: r for r in t3.get("rows", [])}
    executed = closed_loop_means(cl, scorer)
    rows = []
    for name in ("Diffusion policy", "Flow matching"):
        first = predicted.get(f"{name}, first sample")
        chosen = predicted.get(f"{name} + {scorer}")
        if first is None or chosen is None:
            continue
        cells = []
        for s in SIZES:
            f, c = first.get(str(s)), chosen.get(str(s))
            if not isinstance(f, (int, float)) or not isinstance(c, (int, float)) or f <= 0:
                cells.append("–")
                continue
            cell = f"{'holds' if c <= 0.5 * f else 'does not hold'}: {c / f:.2f}"
            ef = executed.get(f"{name}, first sample", {}).get(str(s))
            ec = executed.get(f"{name} + {scorer}", {}).get(str(s))
            if ef is not None and ec is not None:
                cell += f"; executed {ec:.1f} vs {ef:.1f} g"
            cells.append(cell)
        rows.append([name, *cells])
    if not rows:
        return
    doc.table(
        ["ranking halves the predicted error"] + [f"{s} cm" for s in SIZES],
        rows,
        f"Predicted error of the {scorer}-selected chunk over the first sample's (the paper's "
        "claim: at most 0.5). Choosing the lowest prediction of K samples lowers the "
        "prediction by construction; the executed errors (closed loop, g, selected vs first "
        "sample) say whether the choice helps.",
    )


def closed_loop_means(
    cl: dict[str, Any] | None, scorer: str = "W_T"
) -> dict[str, dict[str, float]]:
    """``{Table III label: {size: real error g}}`` from ``table_closed_loop.json``, the
    selected chunks labelled by ``scorer``, the world model that selected them."""
    labels = {"diffusion": "Diffusion policy", "flow": "Flow matching"}
    out: dict[str, dict[str, float]] = {}
    for size, per in ((cl or {}).get("sizes") or {}).items():
        if not isinstance(per, dict):
            continue
        cells = {"Original controller action": (per.get("original") or {}).get("real_g")}
        for obj, name in labels.items():
            o = per.get(obj) or {}
            cells[f"{name}, first sample"] = o.get("first_real_g")
            cells[f"{name} + {scorer}"] = o.get("selected_real_g")
        for label, v in cells.items():
            if isinstance(v, (int, float)):
                out.setdefault(label, {})[str(size)] = float(v)
    return out


def _ranking_figure(
    t3: dict[str, Any], cl: dict[str, Any] | None, figs: Path, scorer: str
) -> str | None:
    plt = headless_pyplot()
    rows = t3.get("rows", [])
    if not rows:
        return None
    real = closed_loop_means(cl, scorer)
    panels = [(f"predicted by {scorer} (Table III)", {r["method"]: r for r in rows})]
    if real:
        panels.append(("real, executed in the simulator", real))
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 3.8), squeeze=False)
    width = 0.8 / len(rows)
    x = np.arange(len(SIZES))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (title, data) in zip(axes[0], panels, strict=True):
        for i, r in enumerate(rows):
            vals = data.get(r["method"]) or {}
            ys = [vals.get(str(s)) for s in SIZES]
            ax.bar(
                x + i * width,
                [np.nan if y is None else y for y in ys],
                width,
                label=r["method"],
                color=colours[i % len(colours)],
            )
        ax.set_xticks(x + 0.4 - width / 2, [f"{s} cm" for s in SIZES])
        ax.set_title(title, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("terminal water error (g)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    figs.mkdir(parents=True, exist_ok=True)
    save_fig(fig, figs / "fig_ranking.png")
    plt.close(fig)
    return f"{FIG_SUBDIR}/fig_ranking.png"
