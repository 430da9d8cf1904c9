"""The report of a pipeline directory: every table of the paper with our numbers beside the
paper's, every figure, the run-grid summary, the physical validation, versions and config.

The report is assembled as a list of blocks (headings, paragraphs, tables, figures) and
rendered twice, to ``report.md`` (figures as files beside it) and to a self-contained
``report.html`` (the same figures embedded as data URIs: the one file can be mailed or
archived on its own), so the two never disagree. Inputs are the files the stages wrote (see
:mod:`rmi_learn.pipeline`); a stage that has not run yet leaves a note in its section instead
of breaking the report. The paper's numbers come from ``paper_reference.json``.
"""

from __future__ import annotations

import base64
import html
import json
import mimetypes
import os
import platform
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import metadata, resources
from pathlib import Path
from typing import Any

from rmi_learn.data.runs import atomic_write_bytes

SIZES = (8, 10, 12)
REPORT_SUBDIR = "report"
FIG_SUBDIR = "figures"


def paper_reference() -> dict[str, Any]:
    """The paper's printed numbers (see ``paper_reference.json``)."""
    text = resources.files("rmi_learn.analysis").joinpath("paper_reference.json").read_text()
    data: dict[str, Any] = json.loads(text)
    return data


# ----------------------------------------------------------------------------- document


@dataclass
class Doc:
    """An ordered list of blocks rendered to Markdown and HTML."""

    blocks: list[tuple[str, Any]] = field(default_factory=list)

    def h(self, level: int, text: str) -> None:
        self.blocks.append((f"h{level}", text))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def table(
        self,
        header: Sequence[str],
        rows: Sequence[Sequence[str]],
        note: str = "",
        text: bool = False,
    ) -> None:
        """A table; ``text`` left-aligns every column (for prose cells rather than numbers)."""
        self.blocks.append(("table", (list(header), [list(r) for r in rows], note, text)))

    def img(self, rel: str, caption: str) -> None:
        self.blocks.append(("img", (rel, caption)))

    def code(self, text: str) -> None:
        self.blocks.append(("code", text))

    def markdown(self) -> str:
        out: list[str] = []
        for kind, val in self.blocks:
            if kind.startswith("h"):
                out += ["#" * int(kind[1]) + " " + val, ""]
            elif kind == "p":
                out += [val, ""]
            elif kind == "code":
                out += ["```", val.rstrip("\n"), "```", ""]
            elif kind == "img":
                rel, cap = val
                out += [f"![{cap}]({rel})", "", f"*{cap}*", ""]
            else:
                header, rows, note, text = val
                align = "---" if text else ":---:"
                out.append("| " + " | ".join(header) + " |")
                out.append("|" + "|".join(["---"] + [align] * (len(header) - 1)) + "|")
                out += ["| " + " | ".join(r) + " |" for r in rows]
                out.append("")
                if note:
                    out += [f"*{note}*", ""]
        return "\n".join(out)

    def html(self, title: str, embed_from: Path | None = None) -> str:
        """The document as one HTML page. With ``embed_from``, each figure is read from that
        directory (its path is relative to it) and embedded as a ``data:`` URI, so the page
        needs no other file; without it, figures are linked by their relative paths."""

        def inline(text: str) -> str:
            # Markdown-style `code` and **bold** only: the report writes nothing else inline.
            t = html.escape(text)
            t = re.sub(r"`([^`]+)`", r"<code>\1</code>", t)
            return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", t)

        body: list[str] = []
        toc: list[str] = []
        for kind, val in self.blocks:
            if kind.startswith("h"):
                level = int(kind[1])
                anchor = re.sub(r"[^a-z0-9]+", "-", val.lower()).strip("-")
                body.append(f'<h{level} id="{anchor}">{inline(val)}</h{level}>')
                if level == 2:
                    toc.append(f'<li><a href="#{anchor}">{inline(val)}</a></li>')
            elif kind == "p":
                body.append(f"<p>{inline(val)}</p>")
            elif kind == "code":
                body.append(f"<pre>{html.escape(val)}</pre>")
            elif kind == "img":
                rel, cap = val
                src = rel if embed_from is None else data_uri(embed_from / rel)
                body.append(
                    f'<figure><img src="{html.escape(src)}" alt="{html.escape(cap)}">'
                    f"<figcaption>{inline(cap)}</figcaption></figure>"
                )
            else:
                header, rows, note, text = val
                t = ['<table class="text">' if text else "<table>", "<thead><tr>"]
                t += [f"<th>{inline(c)}</th>" for c in header]
                t.append("</tr></thead><tbody>")
                for r in rows:
                    cls = ' class="paper"' if r and r[0].startswith("paper") else ""
                    t.append(f"<tr{cls}>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>")
                t.append("</tbody></table>")
                if note:
                    t.append(f'<p class="note">{inline(note)}</p>')
                body.append("".join(t))
        nav = "<nav><b>Contents</b><ol>" + "".join(toc) + "</ol></nav>"
        return (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
            + body[0]
            + nav
            + "\n".join(body[1:])
            + "</body></html>\n"
        )


def data_uri(path: Path) -> str:
    """The file at ``path`` as a ``data:`` URI (base64; media type from its suffix)."""
    kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return f"data:{kind};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;
margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:center}
td:first-child,th:first-child{text-align:left}table.text td,table.text th{text-align:left}
thead{background:#f0f0f0}tr.paper td{color:#666;font-style:italic;background:#fafafa}
figure{margin:1em 0}img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#444}
.note{font-size:.85em;color:#555;margin-top:-.2em}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.85em}
nav{background:#f7f7f7;border:1px solid #ddd;padding:.5em 1em;margin:1em 0}
code{background:#f3f3f3;padding:0 .2em}
"""


# ----------------------------------------------------------------------------- helpers


def _read_json(path: Path) -> Any:
    return json.loads(path.read_text(encoding="utf-8")) if path.exists() else None


def _f(v: Any, digits: int = 2) -> str:
    if v is None:
        return "–"
    try:
        x = float(v)
    except (TypeError, ValueError):
        return str(v)
    if x != x or x in (float("inf"), float("-inf")):
        return "–"
    return f"{x:.{digits}f}"


def _missing(doc: Doc, what: str, stage: str) -> None:
    doc.p(f"*Not available: {what} (stage `{stage}` has not run in this directory).*")


def _headless_pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_fig(fig: Any, path: Path) -> None:
    # savefig into a temporary name and rename, so a killed report leaves no broken PNG.
    atomic_write_bytes(path, lambda f: fig.savefig(f, format="png", dpi=120))


# ----------------------------------------------------------------------------- sections


def _section_grid(doc: Doc, out: Path) -> None:
    import polars as pl

    doc.h(2, "Run grid")
    index_path = out / "sweep" / "index.parquet"
    if not index_path.exists():
        _missing(doc, "the run index", "sweep")
        return
    idx = pl.read_parquet(index_path)
    grid = _read_json(out / "sweep" / "grid.json") or {}
    ok = idx.filter(pl.col("status") == "ok")
    ds = _read_json(out / "dataset" / "dataset.json") or {}
    wall = idx["wall_s"].drop_nulls().to_numpy()
    rows = [
        ["grid", f"{grid.get('name', '?')}: {grid.get('description', '')}"],
        ["runs", str(idx.height)],
        ["finished / failed / unstable"]
        + [
            " / ".join(
                str(idx.filter(pl.col("status") == s).height) for s in ("ok", "failed", "unstable")
            )
        ],
        ["lift success", f"{int(ok['lift_success'].sum())} of {ok.height}"],
        ["stable squeeze", f"{int(ok['stable_squeeze'].sum())} of {ok.height}"],
        ["particle radius", f"{grid.get('radius_m', float('nan')) * 1000:.1f} mm"],
        [
            "simulation wall time",
            f"{wall.sum():.0f} s in total, {wall.mean() if wall.size else 0.0:.1f} s per run",
        ],
    ]
    for key in ("n_fluid", "n_solid"):
        if key in idx.columns:
            vals = idx[key].drop_nulls()
            if vals.len():
                lo, hi = int(vals.min()), int(vals.max())  # type: ignore[arg-type]
                rows.append([f"particles ({key[2:]})", f"{lo}-{hi}"])
    if ds:
        splits = ds.get("splits", {})
        rows.append(
            [
                "runs used for learning",
                f"{ds.get('counts', {}).get('kept', '?')} ("
                + ", ".join(f"{k} {v.get('runs', 0)}" for k, v in sorted(splits.items()))
                + ")",
            ]
        )
    doc.table(["", "value"], rows, text=True)
    if ok.height:
        piv = (
            ok.group_by("size_cm", "porosity", "F_hold")
            .agg(pl.col("lift_success").mean().alias("rate"))
            .sort("size_cm", "porosity", "F_hold")
        )
        holds = sorted(piv["F_hold"].unique().to_list())
        trows = []
        for (size, phi), g in piv.group_by(["size_cm", "porosity"], maintain_order=True):
            rates = dict(zip(g["F_hold"].to_list(), g["rate"].to_list(), strict=True))
            trows.append(
                [f"{size} cm, phi {phi:g}"]
                + [f"{100 * rates[h]:.0f} %" if h in rates else "–" for h in holds]
            )
        doc.p("Lift success by holding force (rows: size and porosity; runs that finished).")
        doc.table(["size, porosity"] + [f"{h:g} N" for h in holds], trows)
    doc.p(
        "Query the grid yourself: `pl.read_parquet('OUT/sweep/index.parquet')` or "
        "`rmi_learn.data.runs.scan_runs('OUT/sweep/runs')` for every recorded channel."
    )


def _copy_fig(src: Path, dst_dir: Path) -> str | None:
    if not src.exists():
        return None
    dst_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(dst_dir / src.name, lambda f: f.write(src.read_bytes()))
    return f"{FIG_SUBDIR}/{src.name}"


def _section_physics(doc: Doc, out: Path, figs: Path, paper: dict[str, Any]) -> None:
    doc.h(2, "Physical behaviour (Sec. VI.A, Figs. 4-6)")
    ana = _read_json(out / "analysis" / "analysis.json")
    if ana is None:
        _missing(doc, "the physical analysis", "analysis")
        return
    captions = {
        "fig4_single_run.png": "Fig. 4 analogue: target and measured grip force and retained "
        "water of one run",
        "fig5_water_per_phase.png": "Fig. 5 analogue: water removed per controller phase over "
        "all runs",
        "fig6_lift_success.png": "Fig. 6 analogue: lift success over porosity and holding force",
        "fig_squeeze_association.png": "Squeeze force vs extra water removed within matched groups",
    }
    for name, cap in captions.items():
        rel = _copy_fig(out / "analysis" / name, figs)
        if rel:
            doc.img(rel, cap)
    p = paper["analysis"]
    assoc = ana.get("squeeze_association") or {}
    rows = []
    slope = assoc.get("slope_g_per_N")
    ci = assoc.get("ci95_g_per_N") or [None, None]
    rows.append(
        [
            "squeeze association (g per N)",
            f"{_f(slope, 3)} [{_f(ci[0], 3)}, {_f(ci[1], 3)}]"
            if slope is not None
            else f"– ({assoc.get('reason', 'not computed')})",
            f"{p['squeeze_association_g_per_N']} "
            f"[{p['squeeze_association_ci95_g_per_N'][0]}, "
            f"{p['squeeze_association_ci95_g_per_N'][1]}]",
        ]
    )
    med = ana.get("water_removed_median_g") or {}
    if med:
        rows.append(
            [
                "median water removed per phase (g)",
                ", ".join(f"{k} {_f(v, 1)}" for k, v in med.items()),
                p["water_per_phase"],
            ]
        )
    doc.table(["quantity", "ours", "paper"], rows, text=True)
    from rmi_learn.analysis.physical import summary_lines

    for line in summary_lines(ana):
        doc.p(line)
    doc.p("All numbers: `analysis/analysis.json`.")


def _ours_then_paper(label: str, cells: list[str], paper: dict[str, Any]) -> list[list[str]]:
    """Our row, then the paper's row for the same method where the paper has one (its cells
    per size are a number or a list of numbers, in the table's column order)."""
    rows = [[label, *cells]]
    ref = paper.get(label)
    if ref is not None:
        vals = [ref[f"{s}cm"] for s in SIZES]
        rows.append(
            [f"paper: {label}"] + [_f(x) for v in vals for x in (v if isinstance(v, list) else [v])]
        )
    return rows


def _wm_rows(
    table: dict[str, Any] | None,
    horizon: str,
    metric_names: Sequence[str],
    paper: dict[str, Any],
) -> list[list[str]]:
    rows: list[list[str]] = []
    for r in (table or {}).get("horizons", {}).get(horizon, []):
        cells = [_f((r.get(f"{s}cm") or {}).get(m)) for s in SIZES for m in metric_names]
        rows += _ours_then_paper(r["method"], cells, paper)
    return rows


def _section_world_models(doc: Doc, out: Path, figs: Path, paper: dict[str, Any]) -> None:
    doc.h(2, "World models (Tables I, II, IV and the lookahead diagnostic)")
    wm_dir = out / "tables" / "wm"
    results = _read_json(wm_dir / "results.json")
    if results is None:
        _missing(doc, "world-model evaluation", "eval-wm")
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
                _f(seen[k].get("latency_ms_8x32"), 1),
            ]
            for k in roles
            if k in seen
        ],
        "Latency: one rollout of 8 chunks x 32 steps on this CPU (median), the planning load.",
    )
    main = "0.64 s"
    t2 = _read_json(wm_dir / "table2.json")
    doc.h(3, "Table II: causal prediction on the test split at 0.64 s")
    doc.table(
        ["method"] + [f"{s} cm {m}" for s in SIZES for m in ("water (g)", "force (N)", "fric.")],
        _wm_rows(t2, main, ("water (g)", "force (N)", "fric."), paper["table2"]),
        "Rows starting with 'paper:' are the paper's numbers. fric. = balanced accuracy over "
        "the four friction classes.",
    )
    t4 = _read_json(wm_dir / "table4.json")
    doc.h(3, "Table IV: state ablation of AC-GRU-WM (water MAE, g, 0.64 s)")
    doc.table(
        ["state"] + [f"{s} cm" for s in SIZES],
        _wm_rows(t4, main, ("water (g)",), paper["table4"]),
    )
    t3 = _read_json(wm_dir / "table3.json")
    doc.h(3, "Lookahead diagnostic: the complete chunk is visible (0.64 s)")
    doc.table(
        ["method"] + [f"{s} cm {m}" for s in SIZES for m in ("water (g)", "force (N)")],
        _wm_rows(t3, main, ("water (g)", "force (N)"), paper["table3_diagnostic"]),
    )
    rel = _horizon_figure(results, figs)
    if rel:
        doc.img(rel, "Forecast water error vs horizon on the test split, per sponge size")


def _horizon_figure(results: list[dict[str, Any]], figs: Path) -> str | None:
    plt = _headless_pyplot()
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
    _save_fig(fig, figs / "fig_horizon.png")
    plt.close(fig)
    return f"{FIG_SUBDIR}/fig_horizon.png"


def _rank_rows(table: dict[str, Any] | None, paper: dict[str, Any]) -> list[list[str]]:
    rows: list[list[str]] = []
    for r in (table or {}).get("rows", []):
        rows += _ours_then_paper(r["method"], [_f(r.get(str(s))) for s in SIZES], paper)
    return rows


def _section_policies(doc: Doc, out: Path, figs: Path, paper: dict[str, Any]) -> None:
    doc.h(2, "Policies and ranking (Tables III, V, S1)")
    rank = out / "tables" / "rank"
    t3 = _read_json(rank / "table3_ranking.json")
    if t3 is None:
        _missing(doc, "ranking tables", "rank")
        return
    nw = t3.get("n_windows", {})
    doc.p(
        f"{t3.get('split', 'test')} windows per size: "
        + ", ".join(f"{s} cm {nw.get(str(s), 0)}" for s in SIZES)
        + f"; K = {t3.get('k', 8)} samples per window."
    )
    doc.h(3, "Table III: W_T-predicted terminal water error (g)")
    doc.table(
        ["method"] + [f"{s} cm" for s in SIZES],
        _rank_rows(t3, paper["table3_ranking"]),
        "Predicted by the scorer that selects the chunk, so biased toward it; the closed-loop "
        "section executes the chunks in the simulator.",
    )
    t5 = _read_json(rank / "table5_imitation.json")
    doc.h(3, "Table V: force MAE and smoothness of one sample (N)")
    rows = []
    for r in (t5 or {}).get("rows", []):
        cells = []
        for s in SIZES:
            v = r.get(str(s)) or {}
            # The reference row has MAE 0 by definition; show it only where data exist.
            has = v.get("smooth_F") is not None
            cells += [_f(v.get(q)) if has else "–" for q in ("MAE_F", "smooth_F")]
        rows += _ours_then_paper(r["method"], cells, paper["table5"])
    doc.table(["method"] + [f"{s} cm {q}" for s in SIZES for q in ("MAE_F", "smooth_F")], rows)
    tS1 = _read_json(rank / "tableS1_cost.json")
    doc.h(3, "Table S1: combined predicted cost J")
    doc.table(["action source"] + [f"{s} cm" for s in SIZES], _rank_rows(tS1, paper["tableS1"]))
    rel = _ranking_figure(t3, _read_json(out / "closed_loop" / "table_closed_loop.json"), figs)
    if rel:
        doc.img(
            rel,
            "Terminal water error per size and action source: as W_T predicts it (left) and "
            "as the simulator realises it (right, closed loop)",
        )


def _closed_loop_means(cl: dict[str, Any] | None) -> dict[str, dict[str, float]]:
    """``{Table III label: {size: real error g}}`` from ``table_closed_loop.json``."""
    labels = {"diffusion": "Diffusion policy", "flow": "Flow matching"}
    out: dict[str, dict[str, float]] = {}
    for size, per in ((cl or {}).get("sizes") or {}).items():
        if not isinstance(per, dict):
            continue
        cells = {"Original controller action": (per.get("original") or {}).get("real_g")}
        for obj, name in labels.items():
            o = per.get(obj) or {}
            cells[f"{name}, first sample"] = o.get("first_real_g")
            cells[f"{name} + W_T"] = o.get("selected_real_g")
        for label, v in cells.items():
            if isinstance(v, (int, float)):
                out.setdefault(label, {})[str(size)] = float(v)
    return out


def _ranking_figure(t3: dict[str, Any], cl: dict[str, Any] | None, figs: Path) -> str | None:
    import numpy as np

    plt = _headless_pyplot()
    rows = t3.get("rows", [])
    if not rows:
        return None
    real = _closed_loop_means(cl)
    panels = [("predicted by W_T (Table III)", {r["method"]: r for r in rows})]
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
    _save_fig(fig, figs / "fig_ranking.png")
    plt.close(fig)
    return f"{FIG_SUBDIR}/fig_ranking.png"


def training_runs(out: Path) -> list[tuple[str, Path]]:
    """(label, run directory) of every world model (``out/wm/*``) and policy
    (``out/policy/*``) the pipeline trained, in that order."""
    runs: list[tuple[str, Path]] = []
    for sub, label in (("wm", "world model"), ("policy", "policy")):
        root = out / sub
        if root.is_dir():
            runs += [(f"{label} {d.name}", d) for d in sorted(root.iterdir()) if d.is_dir()]
    return runs


def training_figure(runs: Sequence[tuple[str, Path]], path: Path) -> bool:
    """Draw the training and validation loss per epoch of each run in ``runs`` ((label, run
    directory) pairs; read from their ``metrics.jsonl``) into the PNG ``path``, one panel
    per run, the selected epoch dotted, the loss axis logarithmic where a run's losses span
    more than a factor of 10. Runs without a training loss (the closed-form world
    models) are left out; returns False, drawing nothing, when none is left."""
    import math

    from matplotlib.ticker import MaxNLocator

    from rmi_learn.metrics_log import loss_curves

    curves = [(label, c) for label, d in runs if (c := loss_curves(d))]
    if not curves:
        return False
    plt = _headless_pyplot()
    ncols = min(4, len(curves))
    nrows = math.ceil(len(curves) / ncols)
    fig, axes = plt.subplots(
        nrows, ncols, figsize=(3.3 * ncols, 2.6 * nrows), squeeze=False, constrained_layout=True
    )
    for ax, (label, c) in zip(axes.flat, curves, strict=False):
        ax.plot(c["epoch"], c["train_loss"], marker=".", label="training")
        if "val_loss" in c:
            ax.plot(c["epoch"], c["val_loss"], marker=".", ls="--", label="validation")
        if "best_epoch" in c:
            ax.axvline(c["best_epoch"][0], color="0.5", ls=":", lw=1)
        values = [v for k in ("train_loss", "val_loss") for v in c.get(k, []) if math.isfinite(v)]
        if values and min(values) > 0 and max(values) > 10 * min(values):
            ax.set_yscale("log")  # losses that fall by decades
        ax.set_title(label, fontsize=9)
        ax.set_xlabel("epoch", fontsize=8)
        ax.tick_params(which="both", labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(curves) :]:
        ax.set_visible(False)
    axes[0][0].set_ylabel("loss", fontsize=8)
    axes[0][0].legend(fontsize=7, frameon=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    _save_fig(fig, path)
    plt.close(fig)
    return True


def _section_training(doc: Doc, out: Path, figs: Path) -> None:
    doc.h(2, "Training curves")
    if not training_figure(training_runs(out), figs / "fig_training.png"):
        _missing(doc, "training curves", "world-models")
        return
    doc.img(
        f"{FIG_SUBDIR}/fig_training.png",
        "Training loss (solid) and validation loss (dashed) per epoch of every trained world "
        "model and policy; the dotted line marks the selected epoch",
    )
    doc.p(
        "A world model's validation loss is its training loss (same weights and scale) on "
        "free rollouts of the validation windows; the recurrent models' training loss is "
        "computed with teacher forcing while it decays. A policy's validation loss is its "
        "objective on the validation windows with fixed noise, and its checkpoint is selected "
        "by a metric of the EMA weights. Linear-ARX and the Baseline are not trained by "
        "gradient and have no curve. Every epoch's numbers: "
        "`wm/<name>/metrics.jsonl`, `policy/<objective>/metrics.jsonl`."
    )


def _section_closed_loop(doc: Doc, out: Path) -> None:
    doc.h(2, "Closed loop: the ranked chunks executed in the simulator")
    md = out / "closed_loop" / "table_closed_loop.md"
    if not md.exists():
        _missing(doc, "closed-loop execution", "closed-loop")
        return
    for kind, val in _md_blocks(md.read_text(encoding="utf-8")):
        if kind == "table":
            doc.table(val[0], val[1])
        else:
            doc.p(val)
    doc.p("Per window and chunk: `closed_loop/closed_loop_windows.parquet`.")


def _section_control(doc: Doc, out: Path, figs: Path) -> None:
    """The goal-reaching benchmark (``control/``), when the preset runs it."""
    ctrl = out / "control"
    md = ctrl / "table_control.md"
    if not md.exists():
        return
    doc.h(2, "Goal-reaching control: every controller executed in the simulator")
    doc.p(
        "From held-out start states, each controller's force-setpoint chunk is executed in the "
        "engine toward a water goal drawn inside the interval a constant grip reaches; the "
        "error is the executed terminal |M_L - g| in grams (docs/control.md)."
    )
    for kind, val in _md_blocks(md.read_text(encoding="utf-8")):
        if kind == "table":
            doc.table(val[0], val[1])
        else:
            doc.p(val)
    for name, caption in (
        ("fig_control.png", "Executed error per controller and sponge size"),
        ("fig_control_scorers.png", "Predicted against executed change of the retained water "
         "over a chunk, per scorer and sponge size"),
    ):
        rel = _copy_fig(ctrl / name, figs)
        if rel:
            doc.img(rel, caption)
    doc.p("Per start state, goal and controller: `control/control_windows.parquet`; every "
          "executed chunk: `control/control_samples.parquet`.")


def _md_blocks(text: str) -> list[tuple[str, Any]]:
    """Paragraphs and pipe tables of a Markdown text written by one of our commands."""
    blocks: list[tuple[str, Any]] = []
    lines = text.splitlines()
    i = 0

    def cells(ln: str) -> list[str]:
        return [c.strip() for c in ln.strip().strip("|").split("|")]

    while i < len(lines):
        ln = lines[i].strip()
        if ln.startswith("|"):
            rows = []
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(cells(lines[i]))
                i += 1
            blocks.append(("table", (rows[0], rows[2:])))
            continue
        if ln:
            blocks.append(("p", ln))
        i += 1
    return blocks


def _section_validation(doc: Doc, out: Path, validation: Path | None) -> None:
    doc.h(2, "Physical validation of the engine")
    src = validation if validation is not None else out / "validation"
    recs = sorted(src.glob("*.json")) if src.is_dir() else []
    if not recs:
        doc.p(
            "*No validation records here. Run `make validation` (it runs "
            "`cargo test --release -p rmi-sph --test validation` with "
            "`RMI_VALIDATION_OUT=OUT/validation`) and re-run `rmi report`. The figures "
            "recorded for the release are in docs/engine.md (Validation).*"
        )
        return
    rows = []
    for path in recs:
        r = json.loads(path.read_text(encoding="utf-8"))
        rows.append(
            [
                str(r.get("case", path.stem)),
                str(r.get("setup", "")),
                str(r.get("measured", "")),
                str(r.get("analytic", "")),
                str(r.get("error", "")),
                "pass" if r.get("pass") else "FAIL",
            ]
        )
    doc.table(["case", "set-up", "measured", "analytic", "error", "test"], rows, text=True)


def _versions() -> list[list[str]]:
    from rmi_learn import __version__
    from rmi_learn.data.runs import git_revision

    rows = [
        ["rmi", __version__],
        ["git revision", git_revision()],
        ["python", sys.version.split()[0]],
        ["platform", platform.platform()],
        ["CPU cores", str(os.cpu_count())],
    ]
    # Read from the installed distributions' metadata: importing torch only to print its
    # version would make the report need it.
    for dist in ("numpy", "polars", "torch", "matplotlib"):
        try:
            rows.append([dist, metadata.version(dist)])
        except metadata.PackageNotFoundError:
            rows.append([dist, "not installed"])
    return rows


def _section_config(doc: Doc, out: Path) -> None:
    doc.h(2, "Versions, configuration and timings")
    doc.table(["component", "version"], _versions(), text=True)
    paths = sorted((out / "stages").glob("*.json"), key=lambda p: p.stat().st_mtime)
    stages = [json.loads(p.read_text(encoding="utf-8")) for p in paths]
    if stages:
        rows = [[m["stage"], f"{m['wall_s']:.1f}"] for m in stages]
        doc.table(["stage", "wall time (s)"], rows, "Stages finished before this report.")
        cmds = [c for m in stages for c in m["commands"]]
        doc.p("Commands run by the pipeline (reproduce any stage by hand):")
        doc.code("\n".join(cmds))
    for name, rel in (("pipeline preset", "pipeline.json"), ("run grid", "sweep/grid.json")):
        cfg = _read_json(out / rel)
        if cfg is not None:
            doc.p(f"{name} (`{rel}`):")
            doc.code(json.dumps(cfg, indent=2))


def build_report(out_dir: str | os.PathLike[str], validation: Path | None = None) -> Doc:
    """Assemble the report of the pipeline directory ``out_dir`` (figures are written to
    ``out_dir/report/figures``)."""
    out = Path(out_dir)
    figs = out / REPORT_SUBDIR / FIG_SUBDIR
    paper = paper_reference()
    cfg = _read_json(out / "pipeline.json") or {}
    doc = Doc()
    doc.h(1, f"rmi report: {cfg.get('name', out.name)}")
    doc.p(
        f"Generated {time.strftime('%Y-%m-%d %H:%M:%S')} from `{out}`. "
        + str(cfg.get("description", ""))
        + " Our numbers come first; rows starting with 'paper:' are the paper's printed "
        "numbers for the same cell. Small presets train on few runs for a few epochs, so "
        "their learning numbers show that the chain works, not the paper's accuracy."
    )
    _section_grid(doc, out)
    _section_physics(doc, out, figs, paper)
    _section_world_models(doc, out, figs, paper)
    _section_policies(doc, out, figs, paper)
    _section_training(doc, out, figs)
    _section_closed_loop(doc, out)
    _section_control(doc, out, figs)
    _section_validation(doc, out, validation)
    _section_config(doc, out)
    return doc


def write_report(
    out_dir: str | os.PathLike[str], validation: Path | None = None
) -> tuple[Path, Path]:
    """Write ``report/report.md`` and ``report/report.html`` under ``out_dir``; returns both
    paths."""
    out = Path(out_dir)
    if not out.is_dir():
        raise FileNotFoundError(f"{out} is not a pipeline output directory")
    doc = build_report(out, validation)
    rdir = out / REPORT_SUBDIR
    rdir.mkdir(parents=True, exist_ok=True)
    md, page = rdir / "report.md", rdir / "report.html"
    title = next((v for k, v in doc.blocks if k == "h1"), "rmi report")
    atomic_write_bytes(md, lambda f: f.write(doc.markdown().encode("utf-8")))
    page_text = doc.html(title, embed_from=rdir)
    atomic_write_bytes(page, lambda f: f.write(page_text.encode("utf-8")))
    # Stale figures of an older layout would confuse a reader browsing the folder.
    keep = {v[0].split("/")[-1] for k, v in doc.blocks if k == "img"}
    for old in (rdir / FIG_SUBDIR).glob("*.png") if (rdir / FIG_SUBDIR).exists() else []:
        if old.name not in keep:
            old.unlink()
    return md, page
