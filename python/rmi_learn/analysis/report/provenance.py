"""The report's last section: the versions it ran with, the stages' wall times and commands,
and the preset and grid configuration."""

from __future__ import annotations

import json
import os
import platform
import sys
from importlib import metadata
from pathlib import Path

from rmi_learn import __version__
from rmi_learn.analysis.report.document import Doc
from rmi_learn.analysis.report.inputs import read_json
from rmi_learn.data.runs import git_revision


def _versions() -> list[list[str]]:
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


def section_config(doc: Doc, out: Path) -> None:
    """Versions, the stages' wall times and commands, the preset and grid configuration."""
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
        cfg = read_json(out / rel)
        if cfg is not None:
            doc.p(f"{name} (`{rel}`):")
            doc.code(json.dumps(cfg, indent=2))
