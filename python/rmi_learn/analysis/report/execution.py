"""The report's sections on chunks executed in the simulator: the closed loop of the ranked
chunks and, when the preset runs it, the goal-reaching benchmark."""

from __future__ import annotations

from pathlib import Path

from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.figure_files import copy_fig
from rmi_learn.analysis.report.inputs import md_blocks, note_missing


def section_closed_loop(doc: Doc, out: Path) -> None:
    """The closed-loop table of the ranked chunks executed in the simulator."""
    doc.h(2, "Closed loop: the ranked chunks executed in the simulator")
    md = out / "closed_loop" / "table_closed_loop.md"
    if not md.exists():
        note_missing(doc, "closed-loop execution", "closed-loop")
        return
    for kind, val in md_blocks(md.read_text(encoding="utf-8")):
        if kind == "table":
            doc.table(val[0], val[1])
        else:
            doc.p(val)
    doc.p("Per window and chunk: `closed_loop/closed_loop_windows.parquet`.")


def section_control(doc: Doc, out: Path, figs: Path) -> None:
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
    for kind, val in md_blocks(md.read_text(encoding="utf-8")):
        if kind == "table":
            doc.table(val[0], val[1])
        else:
            doc.p(val)
    for name, caption in (
        ("fig_control.png", "Executed error per controller and sponge size"),
        (
            "fig_control_scorers.png",
            "Predicted against executed change of the retained water "
            "over a chunk, per scorer and sponge size",
        ),
    ):
        rel = copy_fig(ctrl / name, figs)
        if rel:
            doc.img(rel, caption)
    doc.p(
        "Per start state, goal and controller: `control/control_windows.parquet`; every "
        "executed chunk: `control/control_samples.parquet`."
    )
