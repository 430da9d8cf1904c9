"""The report's section on the physical behaviour (Sec. VI.A, Figs. 4-6): the analysis
figures and its numbers beside the paper's."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rmi_learn.analysis.physical import summary_lines
from rmi_learn.analysis.report.cells import fmt
from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.figure_files import copy_fig
from rmi_learn.analysis.report.inputs import note_missing, read_json


def section_physics(doc: Doc, out: Path, figs: Path, paper: dict[str, Any]) -> None:
    """The analysis figures (copied into ``figs``) and its numbers beside the paper's."""
    doc.h(2, "Physical behaviour (Sec. VI.A, Figs. 4-6)")
    ana = read_json(out / "analysis" / "analysis.json")
    if ana is None:
        note_missing(doc, "the physical analysis", "analysis")
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
        rel = copy_fig(out / "analysis" / name, figs)
        if rel:
            doc.img(rel, cap)
    claim = paper["analysis"]["squeeze_association"]
    assoc = ana.get("squeeze_association") or {}
    rows = []
    slope = assoc.get("slope_g_per_N")
    ci = assoc.get("ci95_g_per_N") or [None, None]
    rows.append(
        [
            "squeeze association (g per N)",
            f"{fmt(slope, 3)} [{fmt(ci[0], 3)}, {fmt(ci[1], 3)}]"
            if slope is not None
            else f"– ({assoc.get('reason', 'not computed')})",
            f"{claim['slope_g_per_N']} [{claim['ci95_g_per_N'][0]}, {claim['ci95_g_per_N'][1]}]",
        ]
    )
    med = ana.get("water_removed_median_g") or {}
    if med:
        rows.append(
            [
                "median water removed per phase (g)",
                ", ".join(f"{k} {fmt(v, 1)}" for k, v in med.items()),
                paper["report_wording"]["water_per_phase"],
            ]
        )
    doc.table(["quantity", "ours", "paper"], rows, text=True)

    for line in summary_lines(ana):
        doc.p(line)
    doc.p("All numbers: `analysis/analysis.json`.")
