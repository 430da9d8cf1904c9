"""The report's section on the goal-reaching benchmark under its protocol: the feedback
baselines first, then what the sensor-mode controllers reach against them."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rmi_learn.analysis.report.document import Doc
from rmi_learn.control_bench.feedback.report import findings


def _cell(line: dict[str, Any]) -> str:
    if not line.get("states"):
        return "-"
    lo, hi = (line.get("median_ci") or [None, None])[:2]
    text = f"{line['median_g']:.2f}"
    if lo is not None:
        text += f" [{lo:.2f}, {hi:.2f}]"
    if line.get("ratio_to_reference") is not None:
        text += f" (x{line['ratio_to_reference']:.2f})"
    return text


def section_control_protocol(doc: Doc, out: Path) -> None:
    """``control_protocol/table_protocol.json``, when the preset runs the stage."""
    path = out / "control_protocol" / "table_protocol.json"
    if not path.exists():
        return
    result = json.loads(path.read_text(encoding="utf-8"))
    p = result["protocol"]
    doc.h(2, "Goal-reaching control: feedback on what the robot can sense")
    doc.p(
        f"Protocol `{p['name']}` (digest `{result['protocol_digest'][:12]}`), executed in the "
        "engine from held-out (porosity, F_hold) groups (leave one group out). Each cell is the "
        "median executed |M_L - g| in grams with its 95 % cluster-bootstrap interval over runs, "
        "and in parentheses the ratio of mean errors to the reference PI of the same "
        f"observation mode ({', '.join(f'{m}: {c}' for m, c in p['references'].items())}). "
        "`pi-privileged` closes the loop on the simulator's own M_L, which no gripper measures; "
        "the sensor-mode controllers see the width, pad loads, tactile contact and shear and "
        "the wrist load, with noise and latency (docs/control.md)."
    )
    sizes = sorted({c["size_cm"] for c in result["summary"]})
    for task in p["tasks"]:
        cells = {c["size_cm"]: c for c in result["summary"] if c["task"] == task}
        rows: list[list[str]] = []
        for name in p["controllers"]:
            lines = [
                next((x for x in cells[s]["controllers"] if x["controller"] == name), {})
                for s in sizes
            ]
            mode = next((x["mode"] for x in lines if x), "")
            rows.append([name, mode, *(_cell(x) for x in lines)])
        doc.p(f"Task `{task}`:")
        doc.table(["controller", "mode", *(f"{s} cm" for s in sizes)], rows)
    for line in findings(result):
        doc.p(line)
    doc.p(
        "Per state, goal and controller: `control_protocol/protocol_rows.parquet`; the tuned "
        "gains and the estimators' fits: `control_protocol/table_protocol.json`."
    )


__all__ = ["section_control_protocol"]
